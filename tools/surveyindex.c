#include "tools/surveyindex.h"

#include <dirent.h>
#include <fitsio.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "sim/fits/fitsout.h"
#include "tools/config.h"

/* An optional integer key of the primary header (-1 when absent: a product of wfisim expose). */
static int32_t key_int(fitsfile *f, const char *key, int *status)
{
    long v = -1;
    if (*status) return -1;
    if (fits_read_key_lng(f, key, &v, NULL, status) == KEY_NO_EXIST) {
        *status = 0;
        fits_clear_errmark();
        return -1;
    }
    return (int32_t)v;
}

wf_status wf_survey_index_read(const char *dir, const char *file, wf_survey_index_row *row)
{
    char path[WF_PATH_MAX + 64];
    snprintf(path, sizeof path, "%s/%s", dir, file);
    memset(row, 0, sizeof *row);
    size_t len = strlen(file);
    if (len >= sizeof row->file || len < 5) return wf_error(WF_ERR_INPUT, "%s: not a product name", path);
    snprintf(row->file, sizeof row->file, "%s", file);
    snprintf(row->truth, sizeof row->truth, "%.*s_truth.fits", (int)(len - 5), file);
    fitsfile *f;
    int status = 0;
    long expid = 0, sca = 0;
    char filter[FLEN_VALUE] = "";
    fits_write_errmark();
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening for the index");
    fits_read_key_lng(f, "EXPOSURE", &expid, NULL, &status);
    fits_read_key_lng(f, "SCA", &sca, NULL, &status);
    fits_read_key_str(f, "FILTER", filter, NULL, &status);
    fits_read_key_dbl(f, "MJD-OBS", &row->mjd, NULL, &status);
    fits_read_key_dbl(f, "RA_PNT", &row->ra, NULL, &status);
    fits_read_key_dbl(f, "DEC_PNT", &row->dec, NULL, &status);
    fits_read_key_dbl(f, "PA_PNT", &row->pa, NULL, &status);
    fits_read_key_dbl(f, "EXPTIME", &row->exptime, NULL, &status);
    row->visit = key_int(f, "VISIT", &status);
    row->orient = key_int(f, "ORIENT", &status);
    row->pointing = key_int(f, "POINTING", &status);
    row->pass = key_int(f, "PASS", &status);
    char digest[FLEN_VALUE] = "";
    if (!status && fits_read_key_str(f, "WFDIGEST", digest, NULL, &status) == KEY_NO_EXIST) {
        status = 0; /* a product of a wfisim before digests */
        fits_clear_errmark();
    }
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    fits_read_key_dbl(f, "CRVAL1", &row->ra_sca, NULL, &status);
    fits_read_key_dbl(f, "CRVAL2", &row->dec_sca, NULL, &status);
    char datasum[FLEN_VALUE] = "";
    fits_read_key_str(f, "DATASUM", datasum, NULL, &status);
    int cs = 0;
    fits_close_file(f, &cs);
    fits_clear_errmark();
    if (status) return wf_fits_error(status, path, "reading the keys of the index (EXPOSURE, SCA, FILTER, MJD-OBS, "
                                     "RA_PNT, DEC_PNT, PA_PNT, EXPTIME; SCI: CRVAL1, CRVAL2, DATASUM)");
    row->expid = (int32_t)expid;
    row->sca = (int32_t)sca;
    snprintf(row->filter, sizeof row->filter, "%s", filter);
    snprintf(row->datasum, sizeof row->datasum, "%s", datasum);
    snprintf(row->digest, sizeof row->digest, "%.64s", digest);
    return WF_OK;
}

static int by_expid_sca(const void *a, const void *b)
{
    const wf_survey_index_row *x = a, *y = b;
    if (x->expid != y->expid) return x->expid < y->expid ? -1 : 1;
    return (x->sca > y->sca) - (x->sca < y->sca);
}

static wf_status write_csv(const char *dir, const wf_survey_index_row *rows, size_t n)
{
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/survey_index.csv", dir);
    FILE *out;
    wf_status st = wf_file_text_open(path, tmp, sizeof tmp, &out);
    if (st) return st;
    fprintf(out, "expid,sca,filter,mjd_mid,visit,orient,pointing,pass,ra_pnt,dec_pnt,pa_pnt,ra_sca,dec_sca,"
                 "exptime,file,truth,datasum,wfdigest\n");
    for (size_t i = 0; i < n; i++) {
        const wf_survey_index_row *r = &rows[i];
        fprintf(out, "%d,%d,%s,%.8f,%d,%d,%d,%d,%.10f,%.10f,%.10f,%.10f,%.10f,%.3f,%s,%s,%s,%s\n", r->expid, r->sca,
                r->filter, r->mjd, r->visit, r->orient, r->pointing, r->pass, r->ra, r->dec, r->pa, r->ra_sca,
                r->dec_sca, r->exptime, r->file, r->truth, r->datasum, r->digest);
    }
    return wf_file_text_commit(out, tmp, path);
}

static wf_status write_fits(const char *dir, const wf_survey_index_row *rows, size_t n)
{
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/survey_index.fits", dir);
    fitsfile *f;
    int status = 0;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    char *tt[] = {"EXPID", "SCA", "FILTER", "MJD_MID", "VISIT", "ORIENT", "POINTING", "PASS", "RA_PNT", "DEC_PNT",
                  "PA_PNT", "RA_SCA", "DEC_SCA", "EXPTIME", "FILE", "TRUTH", "DATASUM", "WFDIGEST"};
    char *tf[] = {"1J", "1J", "8A", "1D", "1J", "1J", "1J", "1J", "1D", "1D", "1D", "1D", "1D", "1D", "40A", "48A", "24A", "64A"};
    char *tu[] = {"", "", "", "d", "", "", "", "", "deg", "deg", "deg", "deg", "deg", "s", "", "", "", ""};
    fits_create_tbl(f, BINARY_TBL, 0, 18, tt, tf, tu, "INDEX", &status);
    fits_write_comment(f, "one row per (exposure, SCA) product, from its headers; -1: not from a plan; WFDIGEST: its inputs", &status);
    for (size_t i = 0; i < n && !status; i++) {
        const wf_survey_index_row *r = &rows[i];
        LONGLONG row = (LONGLONG)i + 1;
        int32_t iv[6] = {r->expid, r->sca, r->visit, r->orient, r->pointing, r->pass};
        const int icol[6] = {1, 2, 5, 6, 7, 8};
        for (int c = 0; c < 6; c++) fits_write_col(f, TINT, icol[c], row, 1, 1, &iv[c], &status);
        double dv[7] = {r->mjd, r->ra, r->dec, r->pa, r->ra_sca, r->dec_sca, r->exptime};
        const int dcol[7] = {4, 9, 10, 11, 12, 13, 14};
        for (int c = 0; c < 7; c++) fits_write_col(f, TDOUBLE, dcol[c], row, 1, 1, &dv[c], &status);
        char *sv[5] = {(char *)r->filter, (char *)r->file, (char *)r->truth, (char *)r->datasum, (char *)r->digest};
        const int scol[5] = {3, 15, 16, 17, 18};
        for (int c = 0; c < 5; c++) fits_write_col(f, TSTRING, scol[c], row, 1, 1, &sv[c], &status);
    }
    return wf_fits_finish(f, tmp, path, wf_fits_error(status, tmp, "writing the index"));
}

wf_status wf_survey_index_write(const char *dir, wf_survey_index_row *rows, size_t n)
{
    if (n) qsort(rows, n, sizeof *rows, by_expid_sca);
    wf_status st = write_fits(dir, rows, n);
    return st ? st : write_csv(dir, rows, n);
}

/* "wfisim_eNNNNNN_scaNN.fits" exactly (not a truth table, a temporary file or another name). */
static int product_name(const char *name)
{
    unsigned e, s;
    int end = 0;
    return strlen(name) == 25 && sscanf(name, "wfisim_e%6u_sca%2u.fits%n", &e, &s, &end) == 2 && end == 25;
}

wf_status wf_survey_index_scan(const char *dir, wf_survey_index_row **out, size_t *n)
{
    *out = NULL;
    *n = 0;
    DIR *d = opendir(dir);
    if (!d) return wf_error(WF_ERR_IO, "%s: cannot open the folder", dir);
    wf_survey_index_row *rows = NULL;
    size_t cap = 0;
    wf_status st = WF_OK;
    for (struct dirent *e; !st && (e = readdir(d));) {
        if (!product_name(e->d_name)) continue;
        if (*n == cap) {
            size_t nc = cap ? 2 * cap : 256;
            wf_survey_index_row *p = realloc(rows, nc * sizeof *p);
            if (!p) { st = wf_error(WF_ERR_NOMEM, "out of memory for the index of %s", dir); break; }
            rows = p;
            cap = nc;
        }
        if (!(st = wf_survey_index_read(dir, e->d_name, &rows[*n]))) (*n)++;
    }
    closedir(d);
    if (st) {
        free(rows);
        *n = 0;
        return st;
    }
    if (*n) qsort(rows, *n, sizeof *rows, by_expid_sca);
    *out = rows;
    return WF_OK;
}
