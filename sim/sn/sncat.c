#include "sim/sn/sncat.h"

#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/fits/fitscheck.h"
#include "sim/fits/fitsout.h"

enum { C_ID, C_Z, C_T0, C_X0, C_X1, C_C, C_DELTA, C_MU, C_HOSTID, C_RA, C_DEC, C_HOSTOFF, C_HOSTCOMP, C_FLAGS, C_HOSTA, NCOL };
static const char *col_name[NCOL] = {"ID", "Z", "T0", "X0", "X1", "C", "DELTA", "MU", "HOSTID",
                                     "RA", "DEC", "HOSTOFF", "HOSTCOMP", "FLAGS", "HOSTA"};
static const char *col_form[NCOL] = {"1K", "1D", "1D", "1D", "1D", "1D", "1D", "1D", "1K",
                                     "1D", "1D", "1D", "1J", "1J", "1D"};
static const char *col_unit[NCOL] = {"", "", "d", "", "", "", "mag", "mag", "", "deg", "deg",
                                     "arcsec", "", "", "arcsec"};

static double **dcol(wf_sn_sample *s, int c)
{
    switch (c) {
    case C_Z: return &s->z;
    case C_T0: return &s->t0;
    case C_X0: return &s->x0;
    case C_X1: return &s->x1;
    case C_C: return &s->c;
    case C_DELTA: return &s->delta;
    case C_MU: return &s->mu;
    case C_RA: return &s->ra;
    case C_DEC: return &s->dec;
    case C_HOSTOFF: return &s->host_offset;
    case C_HOSTA: return &s->host_a;
    default: return NULL;
    }
}

wf_status wf_sn_sample_reserve(wf_sn_sample *s, size_t cap)
{
    if (cap <= s->cap) return WF_OK;
    for (int c = 0; c < NCOL; c++) {
        void **p;
        size_t size;
        if (c == C_ID) p = (void **)&s->id, size = sizeof *s->id;
        else if (c == C_HOSTID) p = (void **)&s->host_id, size = sizeof *s->host_id;
        else if (c == C_HOSTCOMP) p = (void **)&s->host_comp, size = sizeof *s->host_comp;
        else if (c == C_FLAGS) p = (void **)&s->flags, size = sizeof *s->flags;
        else p = (void **)dcol(s, c), size = sizeof(double);
        void *q = realloc(*p, cap * size);
        if (!q) return wf_error(WF_ERR_NOMEM, "SN sample: no memory for %zu supernovae", cap);
        *p = q;
    }
    s->cap = cap;
    return WF_OK;
}

wf_status wf_sn_sample_push(wf_sn_sample *s, size_t *row)
{
    if (s->n == s->cap) {
        wf_status st = wf_sn_sample_reserve(s, s->cap ? 2 * s->cap : 1024);
        if (st) return st;
    }
    size_t i = s->n++;
    s->id[i] = s->host_id[i] = 0;
    s->host_comp[i] = s->flags[i] = 0;
    for (int c = 0; c < NCOL; c++) {
        double **d = dcol(s, c);
        if (d) (*d)[i] = 0.0;
    }
    *row = i;
    return WF_OK;
}

void wf_sn_sample_free(wf_sn_sample *s)
{
    free(s->id);
    free(s->host_id);
    free(s->host_comp);
    free(s->flags);
    for (int c = 0; c < NCOL; c++) {
        double **d = dcol(s, c);
        if (d) free(*d);
    }
    memset(s, 0, sizeof *s);
}

/* "KEY = value / comment" lines into header cards (strings quoted by the caller). */
static void write_cards(fitsfile *f, const char *cards, int *status)
{
    const char *p = cards;
    while (*p && !*status) {
        const char *e = strchr(p, '\n');
        size_t len = e ? (size_t)(e - p) : strlen(p);
        char line[FLEN_CARD + 64], card[FLEN_CARD];
        if (len > 0 && len < sizeof line) {
            memcpy(line, p, len);
            line[len] = '\0';
            int type = 0;
            fits_parse_template(line, card, &type, status);
            fits_write_record(f, card, status);
        }
        p += len + (e ? 1 : 0);
    }
}

wf_status wf_sn_sample_write(const wf_sn_sample *s, const char *path)
{
    char tmp[4200];
    fitsfile *f;
    int status = 0;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "ORIGIN", "wfisim", "supernova sample (wfisim sn generate)", &status);
    char model[72];
    snprintf(model, sizeof model, "%.68s", s->model);
    fits_write_key_str(f, "SNMODEL", model, "SALT model directory (last part)", &status);
    write_cards(f, s->cards, &status);
    fits_create_tbl(f, BINARY_TBL, 0, NCOL, (char **)col_name, (char **)col_form, (char **)col_unit, "SNE", &status);
    fits_write_comment(f, "T0: MJD of rest-frame B-band peak; X0 includes DELTA; HOSTID -1: hostless", &status);
    LONGLONG n = (LONGLONG)s->n;
    if (n > 0) {
        fits_write_col(f, TLONGLONG, C_ID + 1, 1, 1, n, s->id, &status);
        fits_write_col(f, TLONGLONG, C_HOSTID + 1, 1, 1, n, s->host_id, &status);
        fits_write_col(f, TINT, C_HOSTCOMP + 1, 1, 1, n, s->host_comp, &status);
        fits_write_col(f, TINT, C_FLAGS + 1, 1, 1, n, s->flags, &status);
        for (int c = 0; c < NCOL; c++) {
            double **d = dcol((wf_sn_sample *)s, c);
            if (d) fits_write_col(f, TDOUBLE, c + 1, 1, 1, n, *d, &status);
        }
    }
    return wf_fits_finish(f, tmp, path, wf_fits_error(status, tmp, "writing the SN table"));
}

wf_status wf_sn_sample_read(const char *path, wf_sn_sample *out)
{
    memset(out, 0, sizeof *out);
    fitsfile *f;
    int status = 0;
    wf_status hst = wf_fits_check_headers(path);
    if (hst) return hst;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_error(WF_ERR_IO, "%s: cannot open as FITS", path);
    char model[FLEN_VALUE] = "";
    int ks = 0;
    fits_read_key_str(f, "SNMODEL", model, NULL, &ks);
    snprintf(out->model, sizeof out->model, "%s", model);
    wf_status st = WF_OK;
    if (fits_movnam_hdu(f, BINARY_TBL, "SNE", 0, &status)) {
        st = wf_error(WF_ERR_INPUT, "%s: no SNE table (write one with `wfisim sn generate`)", path);
        goto done;
    }
    int col[NCOL];
    for (int c = 0; c < NCOL; c++)
        if (fits_get_colnum(f, CASEINSEN, (char *)col_name[c], &col[c], &status)) {
            st = wf_error(WF_ERR_INPUT, "%s: SNE table has no column %s", path, col_name[c]);
            goto done;
        }
    long n = 0;
    fits_get_num_rows(f, &n, &status);
    if ((st = wf_sn_sample_reserve(out, n > 0 ? (size_t)n : 1))) goto done;
    out->n = (size_t)n;
    if (n > 0) {
        fits_read_col(f, TLONGLONG, col[C_ID], 1, 1, n, NULL, out->id, NULL, &status);
        fits_read_col(f, TLONGLONG, col[C_HOSTID], 1, 1, n, NULL, out->host_id, NULL, &status);
        fits_read_col(f, TINT, col[C_HOSTCOMP], 1, 1, n, NULL, out->host_comp, NULL, &status);
        fits_read_col(f, TINT, col[C_FLAGS], 1, 1, n, NULL, out->flags, NULL, &status);
        for (int c = 0; c < NCOL; c++) {
            double **d = dcol(out, c);
            if (d) fits_read_col(f, TDOUBLE, col[c], 1, 1, n, NULL, *d, NULL, &status);
        }
    }
    if (status) {
        st = wf_fits_error(status, path, "reading the SNE table");
        goto done;
    }
    for (size_t i = 0; i < out->n && !st; i++) {
        for (int c = 0; c < NCOL; c++) {
            double **d = dcol(out, c);
            if (d && !isfinite((*d)[i])) {
                st = wf_error(WF_ERR_INPUT, "%s: SNE row %zu column %s is not finite", path, i + 1, col_name[c]);
                break;
            }
        }
        if (st) break;
        if (!(out->z[i] > 0) || !(out->x0[i] > 0) || out->dec[i] < -90 || out->dec[i] > 90 || out->host_a[i] < 0)
            st = wf_error(WF_ERR_RANGE, "%s: SNE row %zu: Z and X0 must be > 0, DEC in [-90, 90] and HOSTA >= 0", path,
                          i + 1);
    }
done:
    {
        int cs = 0;
        fits_close_file(f, &cs);
    }
    if (st) wf_sn_sample_free(out);
    return st;
}
