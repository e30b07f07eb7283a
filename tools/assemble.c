#include "tools/assemble.h"

#include <ctype.h>
#if defined(__SSE2__)
#include <immintrin.h>
#endif
#include <errno.h>
#include <fitsio.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hal/arena.h"
#include "hal/clock.h"
#include "hal/file.h"
#include "hal/packet.h"
#include "sim/fits/fitscomp.h"
#include "sim/fits/fitsdisk.h"
#include "sim/fits/fitsout.h"
#include "tools/rampfit.h"
#include "firmware/corrnoise.h"
#include "firmware/readout.h"
#include "tools/refpix.h"

/* Per-row bookkeeping: which payloads have covered the row. Rows, not tiles, are the unit,
 * so RESULTANTS and SATURATION packets need not share a tiling to be paired. */
enum { ROW_DATA = 1, ROW_SAT = 2, ROW_FIT = 4 };

/* ---- exposure description from META ------------------------------------------------------ */

typedef struct hdr_line {
    char key[FLEN_KEYWORD];
    const char *value, *comment; /* into the META text copy */
    int line;
    int quoted; /* 'text': a string even if it looks like a number */
} hdr_line;

typedef struct meta {
    char *text; /* owned copy; key/value pointers point into it */
    uint32_t exposure, sca;
    long ncols, nrows;
    int ramp;
    const char *mode, *sampling, *ma_name, *effects;
    int have_seed;
    unsigned long long seed;
    double exptime, gain, read_noise; /* frame time is clock.frame_time */
    double dark_current, full_well, adc_max, saturation_adu, nl_beta, bias;
    int have_dark, have_full_well, have_adc_max, have_sat_adu, have_nl_beta;
    int nonlinearity; /* nonlinearity among the effects: resultants are linearised before fitting */
    wf_clock clock;
    hdr_line *hdr;
    int nhdr;
    hdr_line *img; /* "img.KEY = value" lines: cards for every image HDU (the WCS) */
    int nimg;
} meta;

/* A payload kept until its rows' other half arrives: a SATURATION map whose rows wait for
 * their resultants, or (products.resultants drop, when nothing holds them in the file) a
 * RESULTANTS cube [resultant][row][x] whose rows wait for their saturation. */
typedef struct pending {
    uint32_t first_row, row_count, left; /* left: rows of it not yet fitted */
    void *data;
} pending;

typedef struct pending_list {
    pending *at;
    size_t n, cap;
} pending_list;

enum { HDU_PRIMARY = 1, HDU_SCI, HDU_ERR, HDU_DQ, HDU_RESULTANTS };

typedef struct exposure {
    meta m;
    wf_rampfit_setup fit;
    double *charge; /* ramp: the linearised charge, e-, of every 16-bit ADU value */
    fitsfile *f;
    char path[4096], tmp[4100];
    uint8_t *rows; /* ROW_* per row */
    pending_list sat_wait, res_wait;
    wf_cosmic_record *cr;
    size_t ncr, cr_cap;
    /* compressed products: each image HDU (index hdu - HDU_SCI) in its part file until END */
    fitsfile *part[4];
    char part_path[4][4120];
    /* scratch, grown to the largest run of rows fitted at once (a tile) */
    uint16_t *cube;
    size_t cube_cap;
    float *sci, *err;
    uint32_t *dq;
    size_t out_cap, block_cap; /* pixels per plane; 4-byte words in the planes' block */
    /* DATASUM of the image HDUs (index hdu - 1), summed as their rows are written: every row
     * is written once, so the product is closed without reading the pixels back */
    wf_fits_datasum sum[5];
    /* effects has refpix: the border as received, and one row's corrections [nres][ncols] */
    wf_refpix *rp;
    double *corr;
} exposure;

/* Where an image HDU is being written: the product itself, or its part file (as HDU 2). */
static fitsfile *hdu_file(const exposure *e, int hdu, int *number)
{
    fitsfile *p = e->part[hdu - HDU_SCI];
    *number = p ? 2 : hdu;
    return p ? p : e->f;
}

typedef struct assembler {
    const char *name;
    const wf_assemble_options *opt;
    /* the packet being handled, for messages */
    long packet;
    unsigned long long offset;
    wf_packet_header h;
    exposure **open;
    size_t nopen, open_cap;
    struct { uint32_t exposure, sca; } *done;
    size_t ndone, done_cap;
} assembler;

static const char *kind_name(unsigned kind)
{
    static const char *names[] = {"?", "META", "RESULTANTS", "SINGLE", "SATURATION", "COSMIC", "END",
                                  "REFCOLS", "REFROWS"};
    return kind <= WF_PK_LAST ? names[kind] : "?";
}

/* Every message names the stream, the packet (index, kind, rows, offset) and the exposure. */
static wf_status fail(const assembler *a, wf_status code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static wf_status fail(const assembler *a, wf_status code, const char *fmt, ...)
{
    char detail[768], rows[48];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(detail, sizeof detail, fmt, ap);
    va_end(ap);
    const wf_packet_header *h = &a->h;
    wf_packet_rows_text(h, rows, sizeof rows);
    return wf_error(code, "%s: packet %ld (%s%s%s, exposure %" PRIu32 " SCA %u) at offset %llu: %s",
                    a->name, a->packet, kind_name(h->kind), rows[0] ? ", " : "", rows, h->exposure,
                    (unsigned)h->sca, a->offset, detail);
}

static wf_status fail_fits(const assembler *a, const exposure *e, int status, const char *doing)
{
    wf_fits_error(status, e->tmp, doing);
    char msg[1024];
    snprintf(msg, sizeof msg, "%s", wf_error_message());
    return fail(a, WF_ERR_IO, "%s", msg);
}

/* "16-31, 40, 50-63" for the rows in [lo, hi) whose `bit` is set (want = 1) or clear (0). */
static uint32_t row_ranges(const uint8_t *rows, uint32_t lo, uint32_t hi, uint8_t bit, int want,
                           char *buf, size_t cap)
{
    uint32_t count = 0;
    size_t len = 0;
    int cut = 0;
    buf[0] = '\0';
    for (uint32_t y = lo; y < hi;) {
        if (((rows[y] & bit) != 0) != want) { y++; continue; }
        uint32_t end = y;
        while (end + 1 < hi && ((rows[end + 1] & bit) != 0) == want) end++;
        count += end - y + 1;
        if (!cut) {
            char one[32];
            if (end == y) snprintf(one, sizeof one, "%" PRIu32, y);
            else snprintf(one, sizeof one, "%" PRIu32 "-%" PRIu32, y, end);
            if (len + strlen(one) + 8 < cap) {
                len += (size_t)snprintf(buf + len, cap - len, "%s%s", len ? ", " : "", one);
            } else {
                snprintf(buf + len, cap - len, ", ...");
                cut = 1;
            }
        }
        y = end + 1;
    }
    return count;
}

/* ---- META -------------------------------------------------------------------------------- */

static char *trim(char *s)
{
    while (isspace((unsigned char)*s)) s++;
    char *e = s + strlen(s);
    while (e > s && isspace((unsigned char)e[-1])) *--e = '\0';
    return s;
}

typedef struct kv { const char *key, *value; int line; } kv;

static const char *kv_get(const kv *t, int n, const char *key)
{
    for (int i = 0; i < n; i++)
        if (!strcmp(t[i].key, key)) return t[i].value;
    return NULL;
}

static wf_status meta_number(const assembler *a, const kv *t, int n, const char *key, int required,
                             double *out, int *have)
{
    const char *v = kv_get(t, n, key);
    if (have) *have = v != NULL;
    if (!v) return required ? fail(a, WF_ERR_INPUT, "META has no '%s'", key) : WF_OK;
    char *end;
    errno = 0;
    double d = strtod(v, &end);
    if (end == v || *end || errno || !isfinite(d))
        return fail(a, WF_ERR_INPUT, "META '%s = %s' is not a finite number", key, v);
    *out = d;
    return WF_OK;
}

static wf_status meta_uint(const assembler *a, const kv *t, int n, const char *key,
                           unsigned long long max, unsigned long long *out)
{
    const char *v = kv_get(t, n, key);
    if (!v) return fail(a, WF_ERR_INPUT, "META has no '%s'", key);
    char *end;
    errno = 0;
    unsigned long long u = strtoull(v, &end, 10);
    if (end == v || *end || errno || v[0] == '-' || u > max)
        return fail(a, WF_ERR_INPUT, "META '%s = %s' is not an integer in 0..%llu", key, v, max);
    *out = u;
    return WF_OK;
}

/* ma_reads: resultants separated by '|', each a ','-separated list of 1-based reads or
 * ranges "a-b" (docs/PACKETS.md). */
static wf_status parse_ma_reads(const assembler *a, const char *spec, const char *name,
                                wf_ma_table *ma)
{
    memset(ma, 0, sizeof *ma);
    snprintf(ma->name, sizeof ma->name, "%s", name);
    const char *p = spec;
    long last = 0;
    for (;;) {
        if (ma->nresultants >= WF_MA_MAX_RESULTANTS)
            return fail(a, WF_ERR_INPUT, "META ma_reads '%s': more than %d resultants", spec,
                        WF_MA_MAX_RESULTANTS);
        ma->first[ma->nresultants] = ma->nreads;
        for (;;) {
            while (*p == ' ') p++;
            char *end;
            long lo = strtol(p, &end, 10), hi;
            if (end == p || lo < 1)
                return fail(a, WF_ERR_INPUT, "META ma_reads '%s': expected a read number at '%s'",
                            spec, p);
            p = end;
            hi = lo;
            if (*p == '-') {
                hi = strtol(p + 1, &end, 10);
                if (end == p + 1 || hi < lo)
                    return fail(a, WF_ERR_INPUT, "META ma_reads '%s': bad range at '%s'", spec, p);
                p = end;
            }
            if (hi > WF_MA_MAX_READS * 1000L)
                return fail(a, WF_ERR_INPUT, "META ma_reads '%s': read %ld out of range", spec, hi);
            if (lo <= last)
                return fail(a, WF_ERR_INPUT, "META ma_reads '%s': read %ld not after read %ld",
                            spec, lo, last);
            if (hi - lo + 1 > WF_MA_MAX_READS - ma->nreads)
                return fail(a, WF_ERR_INPUT, "META ma_reads '%s': more than %d reads", spec,
                            WF_MA_MAX_READS);
            for (long r = lo; r <= hi; r++) ma->read[ma->nreads++] = (int)(r - 1);
            last = hi;
            while (*p == ' ') p++;
            if (*p != ',') break;
            p++;
        }
        ma->nresultants++;
        if (*p == '\0') break;
        if (*p != '|')
            return fail(a, WF_ERR_INPUT, "META ma_reads '%s': unexpected '%c'", spec, *p);
        p++;
    }
    ma->first[ma->nresultants] = ma->nreads;
    return WF_OK;
}

static int has_word(const char *list, const char *word)
{
    size_t n = strlen(word);
    for (const char *p = list; p && *p;) {
        while (*p == ',' || *p == ' ') p++;
        const char *e = p;
        while (*e && *e != ',') e++;
        const char *t = e;
        while (t > p && t[-1] == ' ') t--;
        if ((size_t)(t - p) == n && !strncmp(p, word, n)) return 1;
        p = e;
    }
    return 0;
}

/* Keywords a host line may not set: FITS structure, and what the assembler writes itself
 * (a second card with the same name would leave readers to pick one). */
static int reserved_keyword(const char *k)
{
    static const char *fixed[] = {"SIMPLE", "BITPIX", "EXTEND", "END", "XTENSION", "PCOUNT",
                                  "GCOUNT", "CHECKSUM", "DATASUM", "EXTNAME", "BSCALE", "BZERO",
                                  "BUNIT", "CONTINUE", "LONGSTRN", NULL};
    for (int i = 0; fixed[i]; i++)
        if (!strcmp(k, fixed[i])) return 1;
    return !strncmp(k, "NAXIS", 5) || !strncmp(k, "MAREAD", 6);
}

static wf_status parse_hdr_line(const assembler *a, char *key, char *value, int line, hdr_line *out)
{
    size_t n = strlen(key);
    if (n < 1 || n > 8)
        return fail(a, WF_ERR_INPUT, "META line %d: 'hdr.%s' is not a FITS keyword (1-8 characters)",
                    line, key);
    for (size_t i = 0; i < n; i++) {
        char c = (char)toupper((unsigned char)key[i]);
        if (!(isupper((unsigned char)c) || isdigit((unsigned char)c) || c == '-' || c == '_'))
            return fail(a, WF_ERR_INPUT,
                        "META line %d: 'hdr.%s' is not a FITS keyword (A-Z, 0-9, '-', '_')", line, key);
        out->key[i] = c;
    }
    out->key[n] = '\0';
    if (reserved_keyword(out->key))
        return fail(a, WF_ERR_INPUT, "META line %d: 'hdr.%s' is a keyword the assembler writes itself",
                    line, key);
    /* value [/ comment] as in a FITS card: a quoted value may itself hold " / " */
    value = trim(value);
    out->comment = NULL;
    char *rest;
    if (value[0] == '\'') {
        char *w = value, *r = value + 1;
        for (;; r++) {
            if (!*r)
                return fail(a, WF_ERR_INPUT, "META line %d: hdr.%s: unterminated quoted value", line, key);
            if (*r == '\'' && r[1] == '\'') { *w++ = '\''; r++; continue; } /* '' is a quote */
            if (*r == '\'') break;
            *w++ = *r;
        }
        *w = '\0';
        out->quoted = 1;
        rest = trim(r + 1);
        if (*rest && *rest != '/')
            return fail(a, WF_ERR_INPUT, "META line %d: hdr.%s: text after the quoted value", line, key);
        if (*rest == '/') out->comment = trim(rest + 1);
    } else {
        char *slash = strstr(value, " / ");
        if (slash) {
            *slash = '\0';
            out->comment = trim(slash + 3);
        }
        value = trim(value);
    }
    out->value = value;
    out->line = line;
    return WF_OK;
}

static wf_status parse_meta(const assembler *a, const char *payload, size_t len, meta *m)
{
    memset(m, 0, sizeof *m);
    if (!(m->text = malloc(len + 1)))
        return fail(a, WF_ERR_NOMEM, "cannot copy %zu bytes of META text", len);
    memcpy(m->text, payload, len);
    m->text[len] = '\0';
    if (strlen(m->text) != len) return fail(a, WF_ERR_CORRUPT, "META text holds a NUL byte");

    size_t nlines = 1;
    for (size_t i = 0; i < len; i++) nlines += m->text[i] == '\n';
    kv *t = calloc(nlines, sizeof *t);
    m->hdr = calloc(nlines, sizeof *m->hdr);
    m->img = calloc(nlines, sizeof *m->img);
    if (!t || !m->hdr || !m->img) {
        free(t);
        return fail(a, WF_ERR_NOMEM, "cannot parse META of %zu lines", nlines);
    }
    int n = 0, lineno = 0;
    wf_status st = WF_OK;
    for (char *p = m->text, *next; p; p = next) {
        lineno++;
        next = strchr(p, '\n');
        if (next) *next++ = '\0';
        char *line = trim(p);
        if (!*line || *line == '#') continue;
        char *eq = strchr(line, '=');
        if (!eq) {
            st = fail(a, WF_ERR_INPUT, "META line %d: '%.60s' is not 'key = value'", lineno, line);
            goto out;
        }
        *eq = '\0';
        char *key = trim(line), *value = eq + 1;
        if (!strncmp(key, "img.", 4)) {
            hdr_line *h = &m->img[m->nimg];
            if ((st = parse_hdr_line(a, key + 4, value, lineno, h))) goto out;
            for (int i = 0; i < m->nimg; i++)
                if (!strcmp(m->img[i].key, h->key)) {
                    st = fail(a, WF_ERR_INPUT, "META line %d: img.%s given twice (also line %d)",
                              lineno, h->key, m->img[i].line);
                    goto out;
                }
            m->nimg++;
            continue;
        }
        if (!strncmp(key, "hdr.", 4)) {
            hdr_line *h = &m->hdr[m->nhdr];
            if ((st = parse_hdr_line(a, key + 4, value, lineno, h))) goto out;
            for (int i = 0; i < m->nhdr; i++)
                if (!strcmp(m->hdr[i].key, h->key) && strcmp(h->key, "COMMENT") && strcmp(h->key, "HISTORY")) {
                    st = fail(a, WF_ERR_INPUT, "META line %d: hdr.%s given twice (also line %d)",
                              lineno, h->key, m->hdr[i].line);
                    goto out;
                }
            m->nhdr++;
            continue;
        }
        if (kv_get(t, n, key)) {
            st = fail(a, WF_ERR_INPUT, "META line %d: '%s' given twice", lineno, key);
            goto out;
        }
        t[n].key = key;
        t[n].value = trim(value);
        t[n].line = lineno;
        n++;
    }

    unsigned long long u;
    if ((st = meta_uint(a, t, n, "ncols", 1u << 20, &u))) goto out;
    m->ncols = (long)u;
    if ((st = meta_uint(a, t, n, "nrows", 1u << 20, &u))) goto out;
    m->nrows = (long)u;
    if (m->ncols < 1 || m->nrows < 1) {
        st = fail(a, WF_ERR_INPUT, "META shape %ld x %ld is empty", m->ncols, m->nrows);
        goto out;
    }
    if ((st = meta_uint(a, t, n, "exposure", UINT32_MAX, &u))) goto out;
    m->exposure = (uint32_t)u;
    if ((st = meta_uint(a, t, n, "sca", UINT16_MAX, &u))) goto out;
    m->sca = (uint32_t)u;
    if (m->exposure != a->h.exposure || m->sca != a->h.sca) {
        st = fail(a, WF_ERR_INPUT, "META text says exposure %" PRIu32 " SCA %" PRIu32
                  ", its header exposure %" PRIu32 " SCA %u",
                  m->exposure, m->sca, a->h.exposure, (unsigned)a->h.sca);
        goto out;
    }
    m->mode = kv_get(t, n, "mode");
    if (!m->mode || (strcmp(m->mode, "ramp") && strcmp(m->mode, "single"))) {
        st = fail(a, WF_ERR_INPUT, "META mode '%s' (expected ramp or single)", m->mode ? m->mode : "");
        goto out;
    }
    m->ramp = !strcmp(m->mode, "ramp");
    m->sampling = kv_get(t, n, "sampling");
    m->effects = kv_get(t, n, "effects");
    if (kv_get(t, n, "seed")) {
        if ((st = meta_uint(a, t, n, "seed", UINT64_MAX, &m->seed))) goto out;
        m->have_seed = 1;
    }
    if ((st = meta_number(a, t, n, "exptime", 1, &m->exptime, NULL)) ||
        (st = meta_number(a, t, n, "gain", 1, &m->gain, NULL)) ||
        (st = meta_number(a, t, n, "read_noise", 1, &m->read_noise, NULL)) ||
        (st = meta_number(a, t, n, "dark_current", 0, &m->dark_current, &m->have_dark)) ||
        (st = meta_number(a, t, n, "full_well", 0, &m->full_well, &m->have_full_well)) ||
        (st = meta_number(a, t, n, "adc_max", 0, &m->adc_max, &m->have_adc_max)) ||
        (st = meta_number(a, t, n, "saturation_adu", 0, &m->saturation_adu, &m->have_sat_adu)) ||
        (st = meta_number(a, t, n, "nl_beta", 0, &m->nl_beta, &m->have_nl_beta)) ||
        (st = meta_number(a, t, n, "bias", 0, &m->bias, NULL)))
        goto out;
    if (!(m->exptime > 0) || !(m->gain > 0) || !(m->read_noise >= 0)) {
        st = fail(a, WF_ERR_INPUT, "META exptime %g s, gain %g e-/ADU, read_noise %g e-: "
                  "need exptime > 0, gain > 0, read_noise >= 0", m->exptime, m->gain, m->read_noise);
        goto out;
    }
    m->nonlinearity = has_word(m->effects, "nonlinearity");
    if (m->nonlinearity && !m->have_nl_beta) {
        st = fail(a, WF_ERR_INPUT, "META effects include nonlinearity but there is no nl_beta");
        goto out;
    }
    if (m->ramp) {
        const char *reads = kv_get(t, n, "ma_reads");
        m->ma_name = kv_get(t, n, "ma_table");
        if (!reads) {
            st = fail(a, WF_ERR_INPUT, "META has no 'ma_reads' (ramp mode)");
            goto out;
        }
        if ((st = meta_number(a, t, n, "frame_time", 1, &m->clock.frame_time, NULL))) goto out;
        if (!(m->clock.frame_time > 0)) {
            st = fail(a, WF_ERR_INPUT, "META frame_time %g s is not positive", m->clock.frame_time);
            goto out;
        }
        st = parse_ma_reads(a, reads, m->ma_name ? m->ma_name : "", &m->clock.ma);
    }
out:
    free(t);
    return st;
}

static void meta_free(meta *m)
{
    free(m->text);
    free(m->hdr);
    free(m->img);
    memset(m, 0, sizeof *m);
}

/* ---- FITS layout ------------------------------------------------------------------------- */

static void key_dbl(fitsfile *f, const char *key, double v, const char *comment, int *status)
{
    fits_write_key_dbl(f, key, v, -wf_fits_double_digits(v), comment, status);
}

/* Strings past one card's 68 characters go out with the CONTINUE convention. */
static void key_str(fitsfile *f, const char *key, const char *v, const char *comment, int *status)
{
    if (strlen(v) > 68) fits_write_key_longstr(f, key, v, comment, status);
    else fits_write_key_str(f, key, v, comment, status);
}

static void ma_reads_text(const wf_ma_table *ma, int r, char *buf, size_t cap)
{
    size_t len = 0;
    buf[0] = '\0';
    for (int j = ma->first[r]; j < ma->first[r + 1];) {
        int k = j;
        while (k + 1 < ma->first[r + 1] && ma->read[k + 1] == ma->read[k] + 1) k++;
        int n = k == j ? snprintf(buf + len, cap - len, "%s%d", len ? "," : "", ma->read[j] + 1)
                       : snprintf(buf + len, cap - len, "%s%d-%d", len ? "," : "", ma->read[j] + 1,
                                  ma->read[k] + 1);
        if (n < 0 || (size_t)n >= cap - len) return;
        len += (size_t)n;
        j = k + 1;
    }
}

static int write_host_line(fitsfile *f, const hdr_line *h, int *status)
{
    const char *v = h->value, *c = h->comment;
    if (!strcmp(h->key, "COMMENT")) return fits_write_comment(f, v, status);
    if (!strcmp(h->key, "HISTORY")) return fits_write_history(f, v, status);
    if (h->quoted) {
        key_str(f, h->key, v, c, status);
        return *status;
    }
    char *end;
    errno = 0;
    long long i = strtoll(v, &end, 10);
    if (end != v && !*end && !errno) return fits_write_key_lng(f, h->key, i, c, status);
    errno = 0;
    double d = strtod(v, &end);
    if (end != v && !*end && !errno && isfinite(d)) {
        key_dbl(f, h->key, d, c, status);
        return *status;
    }
    key_str(f, h->key, v, c, status);
    return *status;
}

static int write_primary(fitsfile *f, const meta *m, int *status)
{
    fits_create_img(f, BYTE_IMG, 0, NULL, status);
    fits_write_key_lng(f, "EXPOSURE", m->exposure, "exposure id", status);
    fits_write_key_lng(f, "SCA", m->sca, "sensor chip assembly, 1-18", status);
    fits_write_key_str(f, "MODE", m->mode, "ramp: up the ramp; single: single frame", status);
    if (m->sampling) {
        /* the comment names the modes the readout knows, so a new one cannot be left out */
        char cmt[FLEN_COMMENT];
        snprintf(cmt, sizeof cmt, "%s, %s or %s resultants", wf_sampling_name(WF_SAMPLE_PER_READ),
                 wf_sampling_name(WF_SAMPLE_DIRECT), wf_sampling_name(WF_SAMPLE_MOMENTS));
        fits_write_key_str(f, "SAMPLING", m->sampling, cmt, status);
    }
    key_dbl(f, "EXPTIME", m->exptime, "[s] exposure time", status);
    if (m->ramp) {
        key_dbl(f, "FRAMTIME", m->clock.frame_time, "[s] time per full-frame read", status);
        if (m->ma_name) key_str(f, "MA_TABLE", m->ma_name, "MultiAccum table", status);
        fits_write_key_lng(f, "NRESULT", m->clock.ma.nresultants, "resultants", status);
        for (int r = 0; r < m->clock.ma.nresultants; r++) {
            char key[FLEN_KEYWORD], reads[4096], comment[FLEN_COMMENT];
            snprintf(key, sizeof key, "MAREAD%02d", r + 1);
            snprintf(comment, sizeof comment, "reads (1-based) averaged in resultant %d", r + 1);
            ma_reads_text(&m->clock.ma, r, reads, sizeof reads);
            key_str(f, key, reads, comment, status);
        }
    }
    key_dbl(f, "GAIN", m->gain, "[electron/adu] gain", status);
    key_dbl(f, "RDNOISE", m->read_noise,
            m->ramp ? "[electron] read noise per read" : "[electron] read noise per exposure", status);
    if (m->have_dark) key_dbl(f, "DARKCUR", m->dark_current, "[electron/s] dark current", status);
    if (m->have_full_well) key_dbl(f, "FULLWELL", m->full_well, "[electron] full well", status);
    if (m->have_adc_max) key_dbl(f, "ADCMAX", m->adc_max, "[adu] ADC ceiling", status);
    key_dbl(f, "BIAS", m->bias, "[adu] ADC offset, subtracted before fitting", status);
    if (m->have_sat_adu) key_dbl(f, "SATADU", m->saturation_adu, "[adu] saturation level", status);
    if (m->have_nl_beta) key_dbl(f, "NLBETA", m->nl_beta, "nonlinearity: q + NLBETA q^2", status);
    if (m->have_seed) fits_write_key_ulng(f, "SEED", m->seed, "random seed", status);
    if (m->effects) key_str(f, "EFFECTS", m->effects, "detector effects simulated", status);
    return *status;
}

static int write_host_line(fitsfile *f, const hdr_line *h, int *status);

/* The image HDUs share their pixel grid, so each carries the host's img. cards (the WCS).
 * f is the product (the HDU is created there) or a part file whose compressed image
 * exists already; cfitsio named that one, hence EXTNAME updated rather than added. */
static int create_image(fitsfile *f, int in_part, int bitpix, int naxis, long *naxes, const char *extname,
                        const char *bunit, const char *comment, const meta *m, int *status)
{
    if (in_part) {
        fits_update_key_str(f, "EXTNAME", extname, comment, status);
    } else {
        fits_create_img(f, bitpix, naxis, naxes, status);
        fits_write_key_str(f, "EXTNAME", extname, comment, status);
    }
    if (bunit) fits_write_key_str(f, "BUNIT", bunit, "physical unit of the data", status);
    for (int i = 0; i < m->nimg && !*status; i++) write_host_line(f, &m->img[i], status);
    return *status;
}

/* Inverse of q_meas = q + beta q^2 on the rising branch; past the turnover (where the
 * forward law has no preimage) the turnover charge. Written as 2 q / (1 + sqrt(...)) so
 * beta -> 0 has no cancellation. */
static double linearise(double qm, double beta)
{
    double disc = 1.0 + 4.0 * beta * qm;
    return 2.0 * qm / (1.0 + sqrt(disc > 0.0 ? disc : 0.0));
}

static void exposure_free(exposure *e)
{
    if (!e) return;
    if (e->f) {
        int status = 0;
        fits_close_file(e->f, &status);
        fits_clear_errmsg();
        e->f = NULL;
    }
    if (e->tmp[0]) remove(e->tmp);
    meta_free(&e->m);
    pending_list *lists[2] = {&e->sat_wait, &e->res_wait};
    for (int k = 0; k < 2; k++) {
        for (size_t i = 0; i < lists[k]->n; i++) free(lists[k]->at[i].data);
        free(lists[k]->at);
    }
    for (int i = 0; i < 4; i++)
        if (e->part[i]) wf_fits_part_discard(e->part[i], e->part_path[i]);
    free(e->rows);
    free(e->cr);
    free(e->cube);
    free(e->charge);
    free(e->sci); /* the block of all three planes */
    if (e->rp) wf_refpix_free(e->rp);
    free(e->rp);
    free(e->corr);
    free(e);
}

static wf_status reserve_in(const assembler *a, fitsfile *f, const char *path, const char *doing)
{
    wf_status st = wf_fits_reserve_checksum(f, path);
    return st ? fail(a, st, "%s: %s", doing, wf_error_message()) : WF_OK;
}

static wf_status reserve(const assembler *a, exposure *e, const char *doing)
{
    wf_status st = wf_fits_reserve_checksum(e->f, e->tmp);
    return st ? fail(a, st, "%s: %s", doing, wf_error_message()) : WF_OK;
}

static wf_status exposure_open(assembler *a, const void *payload, exposure **out)
{
    const wf_packet_header *h = &a->h;
    *out = NULL;
    for (size_t i = 0; i < a->nopen; i++)
        if (a->open[i]->m.exposure == h->exposure && a->open[i]->m.sca == h->sca)
            return fail(a, WF_ERR_CORRUPT, "second META while the exposure is open (no END before it)");
    for (size_t i = 0; i < a->ndone; i++)
        if (a->done[i].exposure == h->exposure && a->done[i].sca == h->sca)
            return fail(a, WF_ERR_CORRUPT, "exposure already assembled from this stream");
    exposure *e = calloc(1, sizeof *e);
    if (!e) return fail(a, WF_ERR_NOMEM, "cannot allocate exposure state");
    wf_status st = parse_meta(a, payload, h->raw_len, &e->m);
    if (st) goto bad;
    const meta *m = &e->m;
    if (m->ramp && (st = wf_rampfit_setup_init(&m->clock, m->read_noise, &e->fit))) {
        char why[512];
        snprintf(why, sizeof why, "%s", wf_error_message());
        st = fail(a, st, "%s", why);
        goto bad;
    }
    if (m->ramp) {
        /* A resultant's charge depends on its ADU value alone: one table of all 65536 instead
         * of a square root and a division for each of the cube's values (the same numbers) */
        if (!(e->charge = malloc(65536 * sizeof *e->charge))) {
            st = fail(a, WF_ERR_NOMEM, "out of memory for the charge table");
            goto bad;
        }
        for (int adu = 0; adu < 65536; adu++) {
            double v = (adu - m->bias) * m->gain;
            e->charge[adu] = m->nonlinearity ? linearise(v, m->nl_beta) : v;
        }
    }
    if (m->ramp && m->effects && has_word(m->effects, "refpix")) {
        int nres = m->clock.ma.nresultants;
        if (!(e->rp = calloc(1, sizeof *e->rp)) ||
            !(e->corr = malloc((size_t)nres * (size_t)m->ncols * sizeof *e->corr))) {
            st = fail(a, WF_ERR_NOMEM, "out of memory for the reference pixels");
            goto bad;
        }
        if ((st = wf_refpix_init(e->rp, nres, (int)m->ncols, (int)m->nrows, m->bias))) {
            free(e->rp);
            e->rp = NULL;
            goto bad;
        }
    }
    if (!(e->rows = calloc((size_t)m->nrows, 1))) {
        st = fail(a, WF_ERR_NOMEM, "cannot allocate row table of %ld rows", m->nrows);
        goto bad;
    }
    const char *dir = a->opt && a->opt->out_dir && *a->opt->out_dir ? a->opt->out_dir : ".";
    int n = snprintf(e->path, sizeof e->path, "%s/wfisim_e%06" PRIu32 "_sca%02" PRIu32 ".fits", dir,
                     m->exposure, m->sca);
    if (n < 0 || (size_t)n >= sizeof e->path) {
        st = fail(a, WF_ERR_INPUT, "output path under '%s' too long", dir);
        goto bad;
    }
    snprintf(e->tmp, sizeof e->tmp, "%s.tmp", e->path);
    /* A .tmp is only ever a leftover of an interrupted run: replace it. wf_fitsdisk_create
     * takes the name literally (no cfitsio "[ext]" or "!" syntax from a user's directory). */
    remove(e->tmp);
    int status = 0;
    if (wf_fitsdisk_create(&e->f, e->tmp, &status)) {
        e->f = NULL;
        st = fail_fits(a, e, status, "creating the FITS file");
        e->tmp[0] = '\0'; /* not ours: never remove what we could not create */
        goto bad;
    }
    long naxes[3] = {m->ncols, m->nrows, m->ramp ? m->clock.ma.nresultants : 1};
    if (write_primary(e->f, m, &status)) {
        st = fail_fits(a, e, status, "writing the primary header");
        goto bad;
    }
    for (int i = 0; i < m->nhdr; i++) {
        const hdr_line *hl = &m->hdr[i];
        char card[FLEN_CARD];
        int probe = 0;
        if (strcmp(hl->key, "COMMENT") && strcmp(hl->key, "HISTORY") &&
            fits_read_card(e->f, hl->key, card, &probe) == 0) {
            st = fail(a, WF_ERR_INPUT, "META line %d: hdr.%s repeats a keyword written from META",
                      hl->line, hl->key);
            goto bad;
        }
        fits_clear_errmsg(); /* the probe's "keyword not found" */
        if (write_host_line(e->f, hl, &status)) {
            char what[128];
            snprintf(what, sizeof what, "writing hdr.%s (META line %d)", hl->key, hl->line);
            st = fail_fits(a, e, status, what);
            goto bad;
        }
    }
    if ((st = reserve(a, e, "primary header"))) goto bad;
    static const struct {
        int bitpix, naxis;
        const char *name, *bunit, *comment_ramp, *comment_single;
    } img[] = {
        {FLOAT_IMG, 2, "SCI", "electron/s", "count rate from the ramp fit", "count rate"},
        {FLOAT_IMG, 2, "ERR", "electron/s", "1-sigma uncertainty: read and Poisson", NULL},
        {ULONG_IMG, 2, "DQ", NULL, "data quality: 1 DO_NOT_USE, 2 SATURATED, 4 JUMP_DET", NULL},
        {USHORT_IMG, 3, "RESULTANTS", "adu", "averaged reads [resultant][y][x]", NULL},
    };
    const int last = m->ramp && !(a->opt && a->opt->drop_resultants) ? HDU_RESULTANTS : HDU_DQ;
    const int compress = a->opt && a->opt->compress;
    wf_fits_comp comp = {.quantize = a->opt ? a->opt->quantize_level : 0,
                         .dither_seed = wf_fits_comp_dither_seed(m->seed, m->exposure, m->sca)};
    for (int hdu = HDU_SCI; hdu <= last; hdu++) {
        const int k = hdu - HDU_SCI;
        const char *comment = !m->ramp && img[k].comment_single ? img[k].comment_single : img[k].comment_ramp;
        fitsfile *f = e->f;
        const char *fpath = e->tmp;
        char doing[64];
        if (compress) {
            snprintf(e->part_path[k], sizeof e->part_path[k], "%s.%s", e->tmp, img[k].name);
            if ((st = wf_fits_part_create(e->part_path[k], &comp, img[k].bitpix, img[k].naxis, naxes, &e->part[k]))) {
                char why[900];
                snprintf(why, sizeof why, "%s", wf_error_message());
                st = fail(a, st, "%s", why);
                goto bad;
            }
            f = e->part[k];
            fpath = e->part_path[k];
        } else {
            e->sum[hdu - 1].valid = 1; /* summed as the rows are written */
        }
        if (create_image(f, compress, img[k].bitpix, img[k].naxis, naxes, img[k].name, img[k].bunit, comment, m,
                         &status)) {
            snprintf(doing, sizeof doing, "creating %s", img[k].name);
            st = fail_fits(a, e, status, doing);
            goto bad;
        }
        snprintf(doing, sizeof doing, "%s header", img[k].name);
        if ((st = reserve_in(a, f, fpath, doing))) goto bad;
    }
    *out = e;
    return WF_OK;
bad:
    exposure_free(e);
    return st;
}

/* ---- pixels ------------------------------------------------------------------------------ */

static int host_is_little_endian(void)
{
    const uint16_t one = 1;
    return *(const unsigned char *)&one == 1;
}

static wf_status grow(const assembler *a, void **buf, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap) return WF_OK;
    void *p = wf_arena_host_realloc(*buf, *cap * elem, need * elem);
    if (!p) return fail(a, WF_ERR_NOMEM, "cannot allocate %zu bytes for a tile", need * elem);
    *buf = p;
    *cap = need;
    return WF_OK;
}

static wf_status grow_out(const assembler *a, exposure *e, size_t npix)
{
    if (npix <= e->out_cap) return WF_OK;
    /* the three planes of a tile in one block, rounded up to whole huge pages (hal/arena.h):
     * each is filled whole for every tile, and a tile's plane is just under 1 MiB, too little
     * for a huge page of its own; nothing in them outlives the tile */
    _Static_assert(sizeof *e->sci == 4 && sizeof *e->err == 4 && sizeof *e->dq == 4, "4-byte planes");
    const size_t huge = WF_ARENA_HUGE_PAGE;
    void *block = e->sci;
    size_t cap = e->block_cap;
    wf_status st = grow(a, &block, &cap, (3 * npix * 4 + huge - 1) / huge * huge / 4, 4);
    if (st) return st;
    e->sci = block;
    e->err = (float *)block + npix;
    e->dq = (uint32_t *)((float *)block + 2 * npix);
    e->out_cap = npix;
    e->block_cap = cap;
    return WF_OK;
}

static wf_status grow_cube(const assembler *a, exposure *e, size_t n)
{
    void *p = e->cube;
    wf_status st = grow(a, &p, &e->cube_cap, n, sizeof *e->cube);
    e->cube = p;
    return st;
}


/* Fits one row: cube points at resultant 0 of the row, planes `stride` apart. Pixels go to
 * the fitter a chunk at a time (wf_rampfit_pixels fits unsaturated ramps side by side). */
#define FIT_CHUNK 32
static wf_status fit_row(const assembler *a, const exposure *e, uint32_t y, const uint16_t *cube,
                         size_t stride, const uint8_t *sat, float *sci, float *err, uint32_t *dq)
{
    const meta *m = &e->m;
    const int nres = e->fit.nres;
    double q[FIT_CHUNK * WF_MA_MAX_RESULTANTS];
    int first_sat[FIT_CHUNK];
    wf_rampfit_result res[FIT_CHUNK];
    if (e->rp) {
        if (!wf_refpix_ready(e->rp, y))
            return fail(a, WF_ERR_CORRUPT, "row %" PRIu32 " fitted before its reference pixels arrived "
                        "(REFROWS after META, a tile's REFCOLS before its RESULTANTS)", y);
        wf_refpix_correction(e->rp, y, e->corr);
    }
    for (long x0 = 0; x0 < m->ncols; x0 += FIT_CHUNK) {
        int n = m->ncols - x0 < FIT_CHUNK ? (int)(m->ncols - x0) : FIT_CHUNK;
        for (int j = 0; j < n; j++) {
            long x = x0 + j;
            for (int r = 0; r < nres; r++) {
                const uint16_t adu = cube[(size_t)r * stride + (size_t)x];
                if (!e->rp) {
                    q[j * nres + r] = e->charge[adu];
                    continue;
                }
                double v = (adu - e->corr[(size_t)r * m->ncols + x] - m->bias) * m->gain;
                q[j * nres + r] = m->nonlinearity ? linearise(v, m->nl_beta) : v;
            }
            first_sat[j] = sat[x] < nres ? sat[x] : nres;
        }
        int bad;
        wf_status st = wf_rampfit_pixels(&e->fit, q, nres, first_sat, n, res, &bad);
        if (st) {
            char why[512];
            snprintf(why, sizeof why, "%s", wf_error_message());
            return fail(a, st, "ramp fit of pixel (x %ld, y %" PRIu32 "): %s", x0 + (bad > 0 ? bad : 0), y, why);
        }
        for (int j = 0; j < n; j++) {
            const wf_rampfit_result *r = &res[j];
            double var = (r->var_read > 0 ? r->var_read : 0) + (r->var_poisson > 0 ? r->var_poisson : 0);
            sci[x0 + j] = (float)r->rate;
            err[x0 + j] = (float)sqrt(var);
            dq[x0 + j] = r->dq | (first_sat[j] < nres ? WF_DQ_SATURATED : 0u) |
                         (sat[x0 + j] == WF_SAT_PERSISTENCE ? WF_DQ_PERSISTENCE : 0u);
        }
    }
    return WF_OK;
}

static wf_status write_rows(const assembler *a, exposure *e, int hdu, int type, uint32_t y0,
                            uint32_t n, void *data, const char *what)
{
    int status = 0, number;
    fitsfile *f = hdu_file(e, hdu, &number);
    fits_movabs_hdu(f, number, NULL, &status);
    if (f != e->f) { /* a compressed part: cfitsio codes whole rows, which are whole tiles */
        wf_fits_part_write_rows(f, type, (long)e->m.ncols, y0, (long)n, data, &status);
    } else {
        /* TFLOAT is stored as its bit pattern, TUINT with BZERO 2^31; the rows are written in
         * place (nothing reads a tile's planes after they are written) */
        wf_fits_write32(f, (LONGLONG)y0 * e->m.ncols, data, (size_t)n * (size_t)e->m.ncols,
                        type == TUINT ? 0x80000000u : 0, &e->sum[hdu - 1], &status);
    }
    if (status) {
        char doing[96];
        snprintf(doing, sizeof doing, "writing %s rows %" PRIu32 "-%" PRIu32, what, y0, y0 + n - 1);
        return fail_fits(a, e, status, doing);
    }
    return WF_OK;
}

static wf_status write_fit(const assembler *a, exposure *e, uint32_t y0, uint32_t n)
{
    wf_status st;
    if ((st = write_rows(a, e, HDU_SCI, TFLOAT, y0, n, e->sci, "SCI")) ||
        (st = write_rows(a, e, HDU_ERR, TFLOAT, y0, n, e->err, "ERR")) ||
        (st = write_rows(a, e, HDU_DQ, TUINT, y0, n, e->dq, "DQ")))
        return st;
    for (uint32_t y = y0; y < y0 + n; y++) e->rows[y] |= ROW_FIT;
    return WF_OK;
}

static pending *pending_for(pending_list *l, uint32_t y)
{
    for (size_t i = 0; i < l->n; i++)
        if (y >= l->at[i].first_row && y - l->at[i].first_row < l->at[i].row_count) return &l->at[i];
    return NULL;
}

static void pending_done(pending_list *l, pending *p)
{
    if (--p->left) return;
    free(p->data);
    *p = l->at[--l->n];
}

/* Keeps a copy of the current packet's payload (bytes) until `waiting` of its rows are
 * fitted; what names it in messages. */
static wf_status pending_keep(const assembler *a, pending_list *l, const void *payload, size_t bytes,
                              uint32_t waiting, const char *what)
{
    const wf_packet_header *h = &a->h;
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : 8;
        pending *p = realloc(l->at, cap * sizeof *p);
        if (!p) return fail(a, WF_ERR_NOMEM, "cannot grow the table of pending %s", what);
        l->at = p;
        l->cap = cap;
    }
    pending *p = &l->at[l->n];
    if (!(p->data = malloc(bytes)))
        return fail(a, WF_ERR_NOMEM, "cannot keep the %s of %" PRIu32 " rows", what, h->row_count);
    memcpy(p->data, payload, bytes);
    p->first_row = h->first_row;
    p->row_count = h->row_count;
    p->left = waiting;
    l->n++;
    return WF_OK;
}

/* Packet covers rows no earlier packet of its kind covered, and lies inside the SCA. */
static wf_status check_rows(const assembler *a, const exposure *e, uint8_t bit)
{
    const wf_packet_header *h = &a->h;
    if (h->ncols != (uint32_t)e->m.ncols)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " columns, META says %ld", h->ncols, e->m.ncols);
    if (h->row_count == 0 || h->first_row >= (uint32_t)e->m.nrows ||
        h->row_count > (uint32_t)e->m.nrows - h->first_row)
        return fail(a, WF_ERR_CORRUPT, "rows outside the %ld rows META announced", e->m.nrows);
    char dup[256];
    if (row_ranges(e->rows, h->first_row, h->first_row + h->row_count, bit, 1, dup, sizeof dup))
        return fail(a, WF_ERR_CORRUPT, "duplicate: rows %s already received", dup);
    return WF_OK;
}

static wf_status check_size(const assembler *a, uint64_t planes, uint64_t elem)
{
    const wf_packet_header *h = &a->h;
    uint64_t want = planes * h->row_count * h->ncols * elem;
    if (h->raw_len != want)
        return fail(a, WF_ERR_CORRUPT, "payload of %" PRIu32 " bytes, its shape needs %" PRIu64,
                    h->raw_len, want);
    return WF_OK;
}

static wf_status on_resultants(const assembler *a, exposure *e, const void *payload)
{
    const wf_packet_header *h = &a->h;
    const int nres = e->fit.nres;
    if (!e->m.ramp) return fail(a, WF_ERR_CORRUPT, "RESULTANTS in a single-frame exposure");
    wf_status st;
    if ((st = check_rows(a, e, ROW_DATA))) return st;
    if (h->nplanes != (uint32_t)nres)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " resultants, META's MA table has %d", h->nplanes, nres);
    if ((st = check_size(a, (uint64_t)nres, 2))) return st;
    size_t plane = (size_t)h->row_count * (size_t)h->ncols;
    const uint16_t *cube = payload;
    if (!host_is_little_endian()) {
        if ((st = grow_cube(a, e, plane * nres))) return st;
        const unsigned char *b = payload;
        for (size_t i = 0; i < plane * nres; i++) e->cube[i] = (uint16_t)(b[2 * i] | b[2 * i + 1] << 8);
        cube = e->cube;
    }
    const int drop = a->opt && a->opt->drop_resultants;
    if (!drop) {
        int status = 0, number;
        fitsfile *f = hdu_file(e, HDU_RESULTANTS, &number);
        long fp[3] = {1, (long)h->first_row + 1, 1};
        long lp[3] = {e->m.ncols, (long)(h->first_row + h->row_count), nres};
        fits_movabs_hdu(f, number, NULL, &status);
        if (f != e->f) /* a compressed part: each resultant's rows are whole tiles */
            for (int r = 0; r < nres && !status; r++)
                wf_fits_part_write_rows(f, TUSHORT, (long)e->m.ncols, (LONGLONG)r * e->m.nrows + h->first_row,
                                        (long)h->row_count, (void *)(uintptr_t)(cube + (size_t)r * plane), &status);
        else
            fits_write_subset(f, TUSHORT, fp, lp, (void *)(uintptr_t)cube, &status);
        if (status) return fail_fits(a, e, status, "writing RESULTANTS");
        for (int r = 0; f == e->f && r < nres; r++) /* TUSHORT is stored with BZERO 32768 */
            wf_fits_datasum_add16(&e->sum[HDU_RESULTANTS - 1], cube + (size_t)r * plane, plane,
                                  (uint64_t)e->m.ncols * ((uint64_t)h->first_row + (uint64_t)e->m.nrows * (uint64_t)r),
                                  0x8000);
    }
    uint32_t waiting = 0;
    for (uint32_t y = h->first_row; y < h->first_row + h->row_count; y++) {
        e->rows[y] |= ROW_DATA;
        waiting += !(e->rows[y] & ROW_SAT);
    }
    if (drop && waiting &&
        (st = pending_keep(a, &e->res_wait, cube, (size_t)nres * plane * sizeof *cube, waiting, "resultants")))
        return st;

    if ((st = grow_out(a, e, plane))) return st;
    const size_t nc = (size_t)e->m.ncols;
    for (uint32_t y = h->first_row, end = h->first_row + h->row_count; y < end;) {
        if (!(e->rows[y] & ROW_SAT)) { y++; continue; }
        uint32_t y0 = y;
        for (; y < end && (e->rows[y] & ROW_SAT); y++) {
            pending *p = pending_for(&e->sat_wait, y);
            if (!p) return fail(a, WF_ERR_INTERNAL, "saturation of row %" PRIu32 " lost", y);
            size_t k = (size_t)(y - y0) * nc;
            st = fit_row(a, e, y, cube + (size_t)(y - h->first_row) * nc, plane,
                         (const uint8_t *)p->data + (size_t)(y - p->first_row) * nc, e->sci + k, e->err + k,
                         e->dq + k);
            if (st) return st;
            pending_done(&e->sat_wait, p);
        }
        if ((st = write_fit(a, e, y0, y - y0))) return st;
    }
    return WF_OK;
}

static wf_status on_saturation_ramp(const assembler *a, exposure *e, const uint8_t *sat)
{
    const wf_packet_header *h = &a->h;
    const int nres = e->fit.nres;
    const size_t nc = (size_t)e->m.ncols;
    const uint32_t end = h->first_row + h->row_count;
    wf_status st;
    uint32_t waiting = 0;
    for (uint32_t y = h->first_row; y < end; y++) {
        e->rows[y] |= ROW_SAT;
        waiting += !(e->rows[y] & ROW_DATA);
    }
    if ((st = grow_out(a, e, (size_t)h->row_count * nc))) return st;
    /* Rows whose resultants came first were written to the file and not kept: read them back
     * rather than hold cubes for an unknown time (memory stays one tile whatever the order).
     * Dropped resultants were kept in res_wait. */
    for (uint32_t y = h->first_row; y < end;) {
        if (!(e->rows[y] & ROW_DATA)) { y++; continue; }
        uint32_t y0 = y;
        while (y < end && (e->rows[y] & ROW_DATA)) y++;
        size_t n = y - y0, plane = n * nc;
        if (a->opt && a->opt->drop_resultants) {
            for (uint32_t r = y0; r < y; r++) {
                pending *p = pending_for(&e->res_wait, r);
                if (!p) return fail(a, WF_ERR_INTERNAL, "resultants of row %" PRIu32 " lost", r);
                size_t k = (size_t)(r - y0) * nc;
                st = fit_row(a, e, r, (const uint16_t *)p->data + (size_t)(r - p->first_row) * nc,
                             (size_t)p->row_count * nc, sat + (size_t)(r - h->first_row) * nc, e->sci + k,
                             e->err + k, e->dq + k);
                if (st) return st;
                pending_done(&e->res_wait, p);
            }
            if ((st = write_fit(a, e, y0, (uint32_t)n))) return st;
            continue;
        }
        if ((st = grow_cube(a, e, plane * nres))) return st;
        int status = 0, anynul = 0, number;
        fitsfile *f = hdu_file(e, HDU_RESULTANTS, &number);
        long fp[3] = {1, (long)y0 + 1, 1}, lp[3] = {(long)nc, (long)y, nres}, inc[3] = {1, 1, 1};
        fits_movabs_hdu(f, number, NULL, &status);
        fits_read_subset(f, TUSHORT, fp, lp, inc, NULL, e->cube, &anynul, &status);
        if (status) return fail_fits(a, e, status, "reading back RESULTANTS");
        for (uint32_t r = y0; r < y; r++) {
            size_t k = (size_t)(r - y0) * nc;
            st = fit_row(a, e, r, e->cube + k, plane, sat + (size_t)(r - h->first_row) * nc,
                         e->sci + k, e->err + k, e->dq + k);
            if (st) return st;
        }
        if ((st = write_fit(a, e, y0, (uint32_t)n))) return st;
    }
    return waiting ? pending_keep(a, &e->sat_wait, sat, (size_t)h->row_count * nc, waiting, "saturation map") : WF_OK;
}

#if defined(__SSE2__) && defined(__GNUC__)
/* on_single's loop eight pixels at a time (where the CPU has AVX-512): the same double
 * operations lane by lane as the scalar loop, so the same bits; returns the pixels done. */
__attribute__((target("avx512f"))) static size_t single_planes_avx512(const unsigned char *b, size_t npix,
                                                                      double bias, double g, double inv_t,
                                                                      double rn2, float *sci, float *err)
{
    const __m512d vb = _mm512_set1_pd(bias), vg = _mm512_set1_pd(g), vt = _mm512_set1_pd(inv_t);
    const __m512d vr = _mm512_set1_pd(rn2), zero = _mm512_setzero_pd();
    size_t i = 0;
    for (; i + 8 <= npix; i += 8) {
        __m512d adu = _mm512_cvtps_pd(_mm256_loadu_ps((const float *)(const void *)(b + 4 * i)));
        __m512d q = _mm512_mul_pd(_mm512_sub_pd(adu, vb), vg);
        _mm256_storeu_ps(sci + i, _mm512_cvtpd_ps(_mm512_mul_pd(q, vt)));
        /* q > 0 ? q : 0, NaN to 0 as the scalar comparison does */
        __m512d qp = _mm512_maskz_mov_pd(_mm512_cmp_pd_mask(q, zero, _CMP_GT_OQ), q);
        _mm256_storeu_ps(err + i, _mm512_cvtpd_ps(_mm512_mul_pd(_mm512_sqrt_pd(_mm512_add_pd(qp, vr)), vt)));
    }
    return i;
}
#endif

static wf_status on_single(const assembler *a, exposure *e, const void *payload)
{
    const wf_packet_header *h = &a->h;
    if (e->m.ramp) return fail(a, WF_ERR_CORRUPT, "SINGLE in an up-the-ramp exposure");
    wf_status st;
    if ((st = check_rows(a, e, ROW_DATA))) return st;
    if (h->nplanes != 1) return fail(a, WF_ERR_CORRUPT, "nplanes %" PRIu32 ", expected 1", h->nplanes);
    if ((st = check_size(a, 1, 4))) return st;
    size_t npix = (size_t)h->row_count * h->ncols;
    if ((st = grow_out(a, e, npix))) return st;
    const unsigned char *b = payload;
    const int le = host_is_little_endian();
    /* locals, so that the stores cannot alias them: one multiply by 1/t, not two divisions */
    const double g = e->m.gain, inv_t = 1.0 / e->m.exptime, bias = e->m.bias;
    const double rn2 = e->m.read_noise * e->m.read_noise;
    float *restrict sci = e->sci, *restrict err = e->err;
    size_t i = 0;
#if defined(__SSE2__)
    /* two pixels at a time: the same double operations, rounded the same (sqrt is exact), so
     * the same bits as the loop below, which takes the rest */
#if defined(__GNUC__)
    if (le && __builtin_cpu_supports("avx512f")) i = single_planes_avx512(b, npix, bias, g, inv_t, rn2, sci, err);
#endif
    if (le) {
        const __m128d vb = _mm_set1_pd(bias), vg = _mm_set1_pd(g), vt = _mm_set1_pd(inv_t);
        const __m128d vr = _mm_set1_pd(rn2), zero = _mm_setzero_pd();
        for (; i + 2 <= npix; i += 2) {
            float two[2];
            memcpy(two, b + 4 * i, sizeof two);
            __m128d adu = _mm_cvtps_pd(_mm_setr_ps(two[0], two[1], 0.0f, 0.0f));
            __m128d q = _mm_mul_pd(_mm_sub_pd(adu, vb), vg);
            __m128 s2 = _mm_cvtpd_ps(_mm_mul_pd(q, vt));
            /* q > 0 ? q : 0, NaN to 0 as the scalar comparison does */
            __m128d qp = _mm_and_pd(q, _mm_cmpgt_pd(q, zero));
            __m128 e2 = _mm_cvtpd_ps(_mm_mul_pd(_mm_sqrt_pd(_mm_add_pd(qp, vr)), vt));
            float out[4];
            _mm_storeu_ps(out, s2);
            memcpy(sci + i, out, 2 * sizeof *sci);
            _mm_storeu_ps(out, e2);
            memcpy(err + i, out, 2 * sizeof *err);
        }
    }
#endif
    for (; i < npix; i++) {
        float adu;
        if (le) {
            memcpy(&adu, b + 4 * i, 4);
        } else {
            uint32_t u = (uint32_t)b[4 * i] | (uint32_t)b[4 * i + 1] << 8 |
                         (uint32_t)b[4 * i + 2] << 16 | (uint32_t)b[4 * i + 3] << 24;
            memcpy(&adu, &u, 4);
        }
        double q = (adu - bias) * g;
        sci[i] = (float)(q * inv_t);
        err[i] = (float)(sqrt((q > 0 ? q : 0) + rn2) * inv_t);
    }
    if ((st = write_rows(a, e, HDU_SCI, TFLOAT, h->first_row, h->row_count, e->sci, "SCI")) ||
        (st = write_rows(a, e, HDU_ERR, TFLOAT, h->first_row, h->row_count, e->err, "ERR")))
        return st;
    for (uint32_t y = h->first_row; y < h->first_row + h->row_count; y++) e->rows[y] |= ROW_DATA;
    return WF_OK;
}

static wf_status on_saturation(const assembler *a, exposure *e, const void *payload)
{
    const wf_packet_header *h = &a->h;
    wf_status st;
    if ((st = check_rows(a, e, ROW_SAT))) return st;
    if (h->nplanes != 1) return fail(a, WF_ERR_CORRUPT, "nplanes %" PRIu32 ", expected 1", h->nplanes);
    if ((st = check_size(a, 1, 1))) return st;
    if (e->m.ramp) return on_saturation_ramp(a, e, payload);
    size_t npix = (size_t)h->row_count * h->ncols;
    if ((st = grow_out(a, e, npix))) return st;
    const uint8_t *sat = payload;
    for (size_t i = 0; i < npix; i++)
        e->dq[i] = sat[i] == 0 ? WF_DQ_SATURATED : sat[i] == WF_SAT_PERSISTENCE ? WF_DQ_PERSISTENCE : 0u;
    if ((st = write_rows(a, e, HDU_DQ, TUINT, h->first_row, h->row_count, e->dq, "DQ"))) return st;
    for (uint32_t y = h->first_row; y < h->first_row + h->row_count; y++) e->rows[y] |= ROW_SAT | ROW_FIT;
    return WF_OK;
}

static float get_f32(const unsigned char *p)
{
    uint32_t u = (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static uint32_t get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static wf_status on_cosmic(const assembler *a, exposure *e, const void *payload)
{
    const wf_packet_header *h = &a->h;
    if (h->ncols != (uint32_t)e->m.ncols)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " columns, META says %ld", h->ncols, e->m.ncols);
    if ((uint64_t)h->nplanes * 32u != h->raw_len)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " bytes for %" PRIu32 " records of 32 bytes",
                    h->raw_len, h->nplanes);
    if (h->nplanes > SIZE_MAX / sizeof *e->cr - e->ncr)
        return fail(a, WF_ERR_NOMEM, "too many cosmic-ray records");
    size_t need = e->ncr + h->nplanes;
    if (need > e->cr_cap) {
        size_t cap = 2 * e->cr_cap > need ? 2 * e->cr_cap : need;
        wf_cosmic_record *p = realloc(e->cr, cap * sizeof *p);
        if (!p) return fail(a, WF_ERR_NOMEM, "cannot keep %zu cosmic-ray records", need);
        e->cr = p;
        e->cr_cap = cap;
    }
    const unsigned char *b = payload;
    for (uint32_t i = 0; i < h->nplanes; i++, b += 32) {
        wf_cosmic_record *c = &e->cr[e->ncr++];
        c->x0 = get_f32(b);
        c->y0 = get_f32(b + 4);
        c->x1 = get_f32(b + 8);
        c->y1 = get_f32(b + 12);
        c->electrons = get_f32(b + 16);
        c->read = get_u32(b + 20);
        c->id = get_u32(b + 24);
        c->reserved = 0;
    }
    return WF_OK;
}

static int cosmic_by_id(const void *pa, const void *pb)
{
    const wf_cosmic_record *x = pa, *y = pb;
    return (x->id > y->id) - (x->id < y->id);
}

static wf_status write_cosmics(const assembler *a, exposure *e)
{
    if (e->ncr) qsort(e->cr, e->ncr, sizeof *e->cr, cosmic_by_id);
    for (size_t i = 1; i < e->ncr; i++)
        if (e->cr[i].id == e->cr[i - 1].id)
            return fail(a, WF_ERR_CORRUPT, "cosmic-ray id %" PRIu32 " received twice", e->cr[i].id);
    char *ttype[] = {"X0", "Y0", "X1", "Y1", "ELECTRONS", "READ", "ID"};
    char *tform[] = {"1E", "1E", "1E", "1E", "1E", "1V", "1V"};
    char *tunit[] = {"pixel", "pixel", "pixel", "pixel", "electron", "", ""};
    int status = 0;
    fits_create_tbl(e->f, BINARY_TBL, (LONGLONG)e->ncr, 7, ttype, tform, tunit, "COSMICRAYS", &status);
    fits_write_comment(e->f, "cosmic-ray truth: track ends (0-based pixel centres), charge, "
                             "0-based read of the hit, id; sorted by id", &status);
    if (status) return fail_fits(a, e, status, "creating COSMICRAYS");
    wf_status st = reserve(a, e, "COSMICRAYS header");
    if (st || e->ncr == 0) return st;
    float *col = malloc(e->ncr * sizeof *col);
    uint32_t *ucol = malloc(e->ncr * sizeof *ucol);
    if (!col || !ucol) {
        free(col);
        free(ucol);
        return fail(a, WF_ERR_NOMEM, "cannot allocate the COSMICRAYS columns");
    }
    for (int c = 0; c < 7 && !status; c++) {
        for (size_t i = 0; i < e->ncr; i++) {
            const wf_cosmic_record *r = &e->cr[i];
            const float fv[5] = {r->x0, r->y0, r->x1, r->y1, r->electrons};
            if (c < 5) col[i] = fv[c];
            else ucol[i] = c == 5 ? r->read : r->id;
        }
        if (c < 5) fits_write_col(e->f, TFLOAT, c + 1, 1, 1, (LONGLONG)e->ncr, col, &status);
        else fits_write_col(e->f, TUINT, c + 1, 1, 1, (LONGLONG)e->ncr, ucol, &status);
    }
    free(col);
    free(ucol);
    return status ? fail_fits(a, e, status, "writing COSMICRAYS") : WF_OK;
}

/* REFROWS (once) and REFCOLS (each active row once), kept for the correction and the product. */
static wf_status on_refpix(const assembler *a, exposure *e, const void *payload)
{
    const wf_packet_header *h = &a->h;
    wf_refpix *rp = e->rp;
    if (!rp) return fail(a, WF_ERR_CORRUPT, "reference pixels, but META's effects have no refpix");
    if (h->nplanes != (uint32_t)rp->nres)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " resultants, META's MA table has %d", h->nplanes, rp->nres);
    wf_status st;
    if (h->kind == WF_PK_REFROWS) {
        if (rp->have_rows) return fail(a, WF_ERR_CORRUPT, "duplicate: reference rows already received");
        if (h->first_row != 0 || h->row_count != 2 * WF_CN_BORDER || h->ncols != (uint32_t)rp->width)
            return fail(a, WF_ERR_CORRUPT, "reference rows of %" PRIu32 " x %" PRIu32 ", expected %d x %d",
                        h->row_count, h->ncols, 2 * WF_CN_BORDER, rp->width);
        if ((st = check_size(a, (uint64_t)rp->nres, 2))) return st;
        wf_refpix_set_rows(rp, payload);
        return WF_OK;
    }
    if (h->ncols != 2 * WF_CN_BORDER)
        return fail(a, WF_ERR_CORRUPT, "%" PRIu32 " side reference columns, expected %d", h->ncols, 2 * WF_CN_BORDER);
    if (h->row_count == 0 || h->first_row >= (uint32_t)e->m.nrows ||
        h->row_count > (uint32_t)e->m.nrows - h->first_row)
        return fail(a, WF_ERR_CORRUPT, "rows outside the %ld rows META announced", e->m.nrows);
    for (uint32_t y = h->first_row; y < h->first_row + h->row_count; y++)
        if (rp->side_in[y]) return fail(a, WF_ERR_CORRUPT, "duplicate: side reference pixels of row %" PRIu32, y);
    if ((st = check_size(a, (uint64_t)rp->nres, 2))) return st;
    wf_refpix_set_cols(rp, h->first_row, h->row_count, payload);
    return WF_OK;
}

/* products.border: the border as downlinked, two uint16 images (docs/PACKETS.md). */
static wf_status write_border(const assembler *a, exposure *e)
{
    const wf_refpix *rp = e->rp;
    const struct {
        const char *name, *comment;
        long naxes[3];
        const uint16_t *data;
    } hdu[2] = {
        {"REFROWS", "reference rows [resultant][row][X]: full-frame rows 0-3, then the last four",
         {rp->width, 2 * WF_CN_BORDER, rp->nres}, rp->rows},
        {"REFCOLS", "side reference pixels [resultant][y][i]: full-frame columns 0-3, then the last four",
         {2 * WF_CN_BORDER, rp->nrows, rp->nres}, rp->side},
    };
    for (int k = 0; k < 2; k++) {
        int status = 0;
        fits_create_img(e->f, USHORT_IMG, 3, (long *)hdu[k].naxes, &status);
        fits_write_key_str(e->f, "EXTNAME", hdu[k].name, "reference pixels as downlinked", &status);
        fits_write_key_str(e->f, "BUNIT", "adu", "physical unit of the data", &status);
        fits_write_comment(e->f, hdu[k].comment, &status);
        LONGLONG n = (LONGLONG)hdu[k].naxes[0] * hdu[k].naxes[1] * hdu[k].naxes[2];
        fits_write_img(e->f, TUSHORT, 1, n, (void *)(uintptr_t)hdu[k].data, &status);
        if (status) return fail_fits(a, e, status, hdu[k].name);
    }
    return WF_OK;
}

static wf_status on_end(assembler *a, exposure *e, char *last_path, size_t last_path_len)
{
    const wf_packet_header *h = &a->h;
    if (h->row_count != (uint32_t)e->m.nrows)
        return fail(a, WF_ERR_CORRUPT, "END announces %" PRIu32 " rows, META %ld", h->row_count, e->m.nrows);
    char data[300], sat[300];
    uint32_t nr = (uint32_t)e->m.nrows;
    uint32_t miss_d = row_ranges(e->rows, 0, nr, ROW_DATA, 0, data, sizeof data);
    uint32_t miss_s = row_ranges(e->rows, 0, nr, ROW_SAT, 0, sat, sizeof sat);
    const char *dk = e->m.ramp ? "RESULTANTS" : "SINGLE";
    if (miss_d && miss_s && !strcmp(data, sat))
        return fail(a, WF_ERR_CORRUPT, "rows %s missing (no %s, no SATURATION)", data, dk);
    if (miss_d || miss_s) {
        char part_d[400] = "", part_s[400] = "";
        if (miss_d) snprintf(part_d, sizeof part_d, "rows %s missing (no %s)", data, dk);
        if (miss_s) snprintf(part_s, sizeof part_s, "rows %s missing (no SATURATION)", sat);
        return fail(a, WF_ERR_CORRUPT, "%s%s%s", part_d, miss_d && miss_s ? "; " : "", part_s);
    }
    if (e->rp && !e->rp->have_rows) return fail(a, WF_ERR_CORRUPT, "no REFROWS (META's effects have refpix)");
    uint32_t unfit = row_ranges(e->rows, 0, nr, ROW_FIT, 0, data, sizeof data);
    if (unfit || e->sat_wait.n || e->res_wait.n)
        return fail(a, WF_ERR_INTERNAL, "rows %s received but not fitted", data);

    wf_status st;
    for (int k = 0; k < 4; k++) { /* compressed images, in HDU order, after the primary */
        if (!e->part[k]) continue;
        st = wf_fits_part_append(e->f, e->tmp, e->part[k], e->part_path[k], &e->sum[HDU_SCI + k - 1]);
        e->part[k] = NULL;
        if (st) {
            char why[900];
            snprintf(why, sizeof why, "%s", wf_error_message());
            return fail(a, st, "%s", why);
        }
    }
    if ((e->m.effects && has_word(e->m.effects, "cosmic")) || e->ncr)
        if ((st = write_cosmics(a, e))) return st;
    if (e->rp && a->opt && a->opt->border && (st = write_border(a, e))) return st;
    if ((st = wf_fits_checksum_all(e->f, e->tmp, e->sum, (int)(sizeof e->sum / sizeof e->sum[0])))) {
        char why[900];
        snprintf(why, sizeof why, "%s", wf_error_message());
        return fail(a, st, "%s", why);
    }
    int status = 0;
    fits_close_file(e->f, &status);
    e->f = NULL;
    if (status) return fail_fits(a, e, status, "closing (flushing) the FITS file");
    if ((st = wf_file_rename(e->tmp, e->path))) {
        char why[900];
        snprintf(why, sizeof why, "%s", wf_error_message());
        return fail(a, st, "%s", why);
    }
    e->tmp[0] = '\0';
    if (!(a->opt && a->opt->quiet)) fprintf(stderr, "wrote %s\n", e->path);
    if (last_path && last_path_len) snprintf(last_path, last_path_len, "%s", e->path);
    return WF_OK;
}

/* ---- the stream -------------------------------------------------------------------------- */

static exposure *find_open(const assembler *a, size_t *index)
{
    for (size_t i = 0; i < a->nopen; i++)
        if (a->open[i]->m.exposure == a->h.exposure && a->open[i]->m.sca == a->h.sca) {
            if (index) *index = i;
            return a->open[i];
        }
    return NULL;
}

static wf_status handle(assembler *a, const void *payload, char *last_path, size_t last_path_len)
{
    const wf_packet_header *h = &a->h;
    wf_status st;
    if (h->kind == WF_PK_META) {
        exposure *e;
        if ((st = exposure_open(a, payload, &e))) return st;
        if (a->nopen == a->open_cap) {
            size_t cap = a->open_cap ? 2 * a->open_cap : 4;
            exposure **p = realloc(a->open, cap * sizeof *p);
            if (!p) {
                exposure_free(e);
                return fail(a, WF_ERR_NOMEM, "cannot track open exposures");
            }
            a->open = p;
            a->open_cap = cap;
        }
        a->open[a->nopen++] = e;
        return WF_OK;
    }
    size_t idx = 0;
    exposure *e = find_open(a, &idx);
    if (!e) return fail(a, WF_ERR_CORRUPT, "packet of an exposure no META announced (packet before META)");
    switch (h->kind) {
    case WF_PK_RESULTANTS: return on_resultants(a, e, payload);
    case WF_PK_SINGLE: return on_single(a, e, payload);
    case WF_PK_SATURATION: return on_saturation(a, e, payload);
    case WF_PK_COSMIC: return on_cosmic(a, e, payload);
    case WF_PK_REFROWS:
    case WF_PK_REFCOLS: return on_refpix(a, e, payload);
    case WF_PK_END:
        if (a->ndone == a->done_cap) {
            size_t cap = a->done_cap ? 2 * a->done_cap : 8;
            void *p = realloc(a->done, cap * sizeof *a->done);
            if (!p) return fail(a, WF_ERR_NOMEM, "cannot track finished exposures");
            a->done = p;
            a->done_cap = cap;
        }
        if ((st = on_end(a, e, last_path, last_path_len))) return st;
        a->done[a->ndone].exposure = e->m.exposure;
        a->done[a->ndone].sca = e->m.sca;
        a->ndone++;
        exposure_free(e);
        a->open[idx] = a->open[--a->nopen];
        return WF_OK;
    default: return fail(a, WF_ERR_CORRUPT, "unknown packet kind %u", (unsigned)h->kind);
    }
}

wf_status wf_assemble_stream(FILE *in, const char *name, const wf_assemble_options *opt,
                             char *last_path, size_t last_path_len)
{
    return wf_assemble_source(wf_packet_read_file, in, name, opt, last_path, last_path_len);
}

wf_status wf_assemble_source(wf_packet_read_fn read, void *ctx, const char *name,
                             const wf_assemble_options *opt, char *last_path, size_t last_path_len)
{
    if (last_path && last_path_len) last_path[0] = '\0';
    assembler a = {.name = name ? name : "-", .opt = opt};
    wf_packet_reader r;
    wf_packet_reader_open_source(&r, read, ctx, a.name);
    wf_status st = WF_OK;
    for (;;) {
        const void *payload;
        int eof;
        unsigned long long at = r.offset;
        st = wf_packet_reader_next(&r, &a.h, &payload, &eof);
        if (st) break;
        if (eof) break;
        a.packet = r.count;
        a.offset = at;
        if ((st = handle(&a, payload, last_path, last_path_len))) break;
    }
    if (st == WF_OK && a.nopen) {
        const meta *m = &a.open[0]->m;
        st = wf_error(WF_ERR_CORRUPT, "%s: stream ends after %ld packets without END for exposure %"
                      PRIu32 " SCA %" PRIu32 "%s; no FITS written for it", a.name, r.count,
                      m->exposure, m->sca, a.nopen > 1 ? " (and others)" : "");
    } else if (st == WF_OK && a.ndone == 0) {
        st = wf_error(WF_ERR_CORRUPT, "%s: stream holds no exposure (%ld packets)", a.name, r.count);
    } else if (st && a.nopen) {
        /* the reader's own message already names stream and packet; say what it cost */
        char why[900];
        snprintf(why, sizeof why, "%s", wf_error_message());
        const meta *m = &a.open[0]->m;
        st = wf_error(st, "%s; exposure %" PRIu32 " SCA %" PRIu32 "%s abandoned, no FITS written",
                      why, m->exposure, m->sca, a.nopen > 1 ? " (and others)" : "");
    }
    for (size_t i = 0; i < a.nopen; i++) exposure_free(a.open[i]);
    free(a.open);
    free(a.done);
    wf_packet_reader_close(&r);
    return st;
}
