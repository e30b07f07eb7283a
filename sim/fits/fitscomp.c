#include "sim/fits/fitscomp.h"
#include "sim/fits/fitsout.h"
#include "sim/fits/rice.h"

#include <fitsio2.h>

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* cfitsio stores a requested quantize level of 0 (floats kept exact) as this (imcompress.c) */
#define CFITSIO_NO_QUANTIZE 9999.0f

int wf_fits_comp_dither_seed(uint64_t seed, uint32_t exposure, uint32_t sca)
{
    /* splitmix64's finaliser over the three keys: neighbouring exposures and SCAs get
     * unrelated seeds */
    uint64_t z = seed ^ ((uint64_t)exposure << 20) ^ ((uint64_t)sca << 52) ^ 0x9e3779b97f4a7c15ull;
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (int)(z % 10000u) + 1;
}

wf_status wf_fits_part_create(const char *path, const wf_fits_comp *c, int bitpix, int naxis,
                              long *naxes, fitsfile **f)
{
    if (!(c->quantize == 0 || c->quantize >= 1))
        return wf_error(WF_ERR_RANGE, "%s: products.quantize_level %g: 0 (lossless) or at least 1", path, c->quantize);
    if (c->dither_seed < 1 || c->dither_seed > 10000)
        return wf_error(WF_ERR_INTERNAL, "%s: dither seed %d outside 1..10000", path, c->dither_seed);
    unlink(path);
    int status = 0;
    const int is_float = bitpix == FLOAT_IMG || bitpix == DOUBLE_IMG;
    long tile[3] = {naxes[0], 1, 1}; /* one row: any run of whole rows is whole tiles */
    *f = NULL;
    if (fits_create_diskfile(f, path, &status)) return wf_fits_error(status, path, "creating a part file");
    fits_create_img(*f, BYTE_IMG, 0, NULL, &status);
    fits_set_compression_type(*f, is_float && c->quantize == 0 ? GZIP_2 : RICE_1, &status);
    fits_set_tile_dim(*f, naxis, tile, &status);
    if (is_float) {
        fits_set_quantize_level(*f, (float)c->quantize, &status);
        /* dither 2 keeps exact zeros exact */
        if (c->quantize > 0) fits_set_quantize_method(*f, SUBTRACTIVE_DITHER_2, &status);
        fits_set_dither_seed(*f, c->dither_seed, &status);
    }
    fits_create_img(*f, bitpix, naxis, naxes, &status);
    if (status) {
        wf_status st = wf_fits_error(status, path, "creating a compressed image");
        wf_fits_part_discard(*f, path);
        *f = NULL;
        return st;
    }
    return WF_OK;
}

void wf_fits_part_discard(fitsfile *f, const char *path)
{
    int status = 0;
    if (f) fits_close_file(f, &status);
    fits_clear_errmsg();
    unlink(path);
}

/* Bytes of one heap element of column c (a 'P' or 'Q' descriptor column). */
static int heap_width(fitsfile *f, int c, long *width, int *status)
{
    int type = 0;
    long repeat = 0;
    if (fits_get_coltype(f, c, &type, &repeat, width, status)) return *status;
    if (*width < 1) *width = 1;
    return 0;
}

static wf_status append(fitsfile *dst, const char *dst_path, fitsfile *part, const char *part_path,
                        wf_fits_datasum *sum)
{
    int status = 0;
    wf_fits_datasum ds = {0, 0, 0};
    if (fits_movabs_hdu(part, 2, NULL, &status) || fits_flush_file(part, &status))
        return wf_fits_error(status, part_path, "finishing the compressed image");
    /* the header as cfitsio wrote it (a binary table, NAXIS2 tiles, PCOUNT heap bytes) */
    if (fits_copy_header(part, dst, &status)) return wf_fits_error(status, dst_path, "copying a compressed header");
    LONGLONG ha, da, ea, hb, db, eb;
    fits_get_hduaddrll(part, &ha, &da, &ea, &status);
    fits_get_hduaddrll(dst, &hb, &db, &eb, &status);
    if (status) return wf_fits_error(status, dst_path, "locating a compressed image");
    FITSfile *A = part->Fptr, *B = dst->Fptr;
    const LONGLONG nrows = A->numrows, fixed = A->rowlength * nrows;
    size_t cap = (size_t)(fixed > 65536 ? fixed : 65536);
    unsigned char *buf = malloc(cap);
    if (!buf) return wf_error(WF_ERR_NOMEM, "%s: no memory to append a compressed image", dst_path);
    /* the table rows (descriptors, ZSCALE and ZZERO) as they are; the descriptors are
     * rewritten below */
    ffmbyt(part, da, REPORT_EOF, &status);
    ffgbyt(part, fixed, buf, &status);
    ffmbyt(dst, db, IGNORE_EOF, &status);
    ffpbyt(dst, fixed, buf, &status);
    LONGLONG heap = 0;
    wf_status st = WF_OK;
    for (LONGLONG r = 1; r <= nrows && !status && !st; r++)
        for (int c = 1; c <= A->tfield && !status && !st; c++) {
            if (A->tableptr[c - 1].tdatatype >= 0) continue; /* not a variable-length column */
            LONGLONG len = 0, off = 0;
            long width = 1;
            if (ffgdesll(part, c, r, &len, &off, &status) || heap_width(part, c, &width, &status)) break;
            const LONGLONG nb = len * width, at = da + A->heapstart + off;
            if (nb > 0) {
                if ((size_t)nb > cap) {
                    unsigned char *p = realloc(buf, (size_t)nb);
                    if (!p) {
                        st = wf_error(WF_ERR_NOMEM, "%s: no memory for a compressed tile of %lld bytes", dst_path,
                                      (long long)nb);
                        break;
                    }
                    buf = p;
                    cap = (size_t)nb;
                }
                ffmbyt(part, at, REPORT_EOF, &status);
                ffgbyt(part, nb, buf, &status);
                ffmbyt(dst, db + B->heapstart + heap, IGNORE_EOF, &status);
                ffpbyt(dst, nb, buf, &status);
                wf_fits_datasum_add_bytes(&ds, buf, (size_t)nb, (uint64_t)(B->heapstart + heap));
            }
            ffpdes(dst, c, r, len, nb > 0 ? heap : 0, &status);
            heap += nb;
        }
    /* the table rows as they now stand (the descriptors rewritten), from dst; with the heap
     * right after them (cfitsio's THEAP default: nothing between), the data unit is summed */
    if (!st && !status && B->heapstart == fixed && (size_t)fixed <= cap) {
        ffmbyt(dst, db, REPORT_EOF, &status);
        ffgbyt(dst, fixed, buf, &status);
        wf_fits_datasum_add_bytes(&ds, buf, (size_t)fixed, 0);
        ds.valid = !status;
    }
    free(buf);
    if (st) return st;
    if (status) return wf_fits_error(status, dst_path, "appending a compressed image");
    if (heap != A->heapsize) {
        /* tiles written twice left dead bytes in the part's heap: none are copied */
        fits_modify_key_lng(dst, "PCOUNT", heap, "&", &status);
        B->heapsize = heap;
        ffrdef(dst, &status);
        if (status) return wf_fits_error(status, dst_path, "setting PCOUNT of a compressed image");
    }
    *sum = ds;
    return WF_OK;
}

wf_status wf_fits_part_append(fitsfile *dst, const char *dst_path, fitsfile *part, const char *part_path,
                              wf_fits_datasum *sum)
{
    wf_fits_datasum ds = {0, 0, 0}; /* append sets it only when it succeeds */
    wf_status st = append(dst, dst_path, part, part_path, &ds);
    if (sum) *sum = ds;
    wf_fits_part_discard(part, part_path);
    return st;
}

/* The k-th smallest of v[0..n-1], all finite and >= +0 (v is overwritten): a radix select on
 * the bit patterns, whose order as unsigned integers is the floats' order for such values.
 * Three digits (bits 31-20, 19-10, 9-0), each a histogram of the values that share the
 * digits found so far: exact, and branch-light where a quickselect's comparisons with the
 * pivot are a coin toss on noise (the assembler's rows). */
static float select_kth(float *v, long n, long k)
{
    enum { B1 = 12, B2 = 10, B3 = 10 };
    uint32_t h[1u << B1], h2[1u << B2], h3[1u << B3];
    memset(h, 0, sizeof h);
    memset(h2, 0, sizeof h2);
    memset(h3, 0, sizeof h3);
    for (long i = 0; i < n; i++) {
        uint32_t u;
        memcpy(&u, &v[i], sizeof u);
        h[u >> (B2 + B3)]++;
    }
    uint32_t d1 = 0, left = (uint32_t)k;
    while (left >= h[d1]) left -= h[d1++];
    /* the values in that bin, moved to the front of v */
    long m = 0;
    for (long i = 0; i < n; i++) {
        uint32_t u;
        memcpy(&u, &v[i], sizeof u);
        if (u >> (B2 + B3) != d1) continue;
        h2[(u >> B3) & ((1u << B2) - 1)]++;
        v[m++] = v[i];
    }
    uint32_t d2 = 0;
    while (left >= h2[d2]) left -= h2[d2++];
    uint32_t high = d1 << B2 | d2;
    for (long i = 0; i < m; i++) {
        uint32_t u;
        memcpy(&u, &v[i], sizeof u);
        if (u >> B3 == high) h3[u & ((1u << B3) - 1)]++;
    }
    uint32_t d3 = 0;
    while (left >= h3[d3]) left -= h3[d3++];
    uint32_t u = high << B3 | d3;
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

double wf_fits_row_noise(const float *row, long n, float *scratch)
{
    /* third-order differences 2 x_i - x_(i-2) - x_(i+2): smooth signal (sky gradients,
     * the wings of sources) cancels, the noise of independent pixels is sqrt 6 sigma; the
     * median of their absolute values is 0.6745 sqrt 6 sigma for Gaussian noise, robust to
     * the few pixels a source or a cosmic ray takes */
    long m = 0;
    for (long i = 2; i + 2 < n; i++) {
        float d = fabsf(2.0f * row[i] - row[i - 2] - row[i + 2]);
        if (isfinite(d)) scratch[m++] = d; /* >= +0: select_kth's domain */
    }
    if (m < 1) return 0;
    return 0.6052697 * select_kth(scratch, m, (m - 1) / 2);
}

static _Atomic long own_tiles; /* tiles coded by rice.c, for wf_fits_own_rice_tiles */

long wf_fits_own_rice_tiles(void) { return own_tiles; }

/* The XOR that turns pixels of `type` into the integers a Rice-coded HDU of one-row tiles
 * stores (flip 0 or the sign bit of the unsigned types' BZERO), when wfisim's coder can
 * write its tiles: 1, else 0 (cfitsio codes them). */
/* What both of wfisim's own tile writers need: a Rice-coded HDU of one-row tiles, without
 * null substitution or scaling. */
static int rice_rows(const FITSfile *F, long ncols)
{
    if (!F->compressimg || F->compress_type != RICE_1 || F->cn_compressed < 1 || F->cn_zblank > 0 ||
        F->cn_bscale != 1.0 || F->tilesize[0] != ncols)
        return 0;
    for (int k = 1; k < F->zndim; k++)
        if (F->tilesize[k] != 1) return 0;
    return 1;
}

static int own_rice(const fitsfile *f, int type, long ncols, int *bytepix, uint32_t *flip)
{
    const FITSfile *F = f->Fptr;
    if (!rice_rows(F, ncols) || F->cn_zscale > 0 || F->request_lossy_int_compress) return 0;
    const double z = F->cn_actual_bzero;
    if (F->zbitpix == SHORT_IMG && ((type == TUSHORT && z == 32768.0) || (type == TSHORT && z == 0.0))) {
        *bytepix = 2;
        *flip = type == TUSHORT ? 0x8000u : 0u;
        return 1;
    }
    if (F->zbitpix == LONG_IMG && ((type == TUINT && z == 2147483648.0) || (type == TINT && z == 0.0))) {
        *bytepix = 4;
        *flip = type == TUINT ? 0x80000000u : 0u;
        return 1;
    }
    return 0;
}

/* 1 when wfisim can write the tiles of this quantized float HDU of one-row tiles itself
 * (as cfitsio would, Rice coded, subtractively dithered with a seed already fixed), else 0. */
static int own_quantized(const fitsfile *f, long ncols)
{
    const FITSfile *F = f->Fptr;
    return rice_rows(F, ncols) && F->cn_zscale > 0 && F->cn_zzero > 0 && F->zbitpix == FLOAT_IMG &&
           F->cn_bzero == 0.0 && F->dither_seed > 0 &&
           (F->quantize_method == SUBTRACTIVE_DITHER_1 || F->quantize_method == SUBTRACTIVE_DITHER_2);
}

static int all_finite(const float *v, long n)
{
    int ok = 1;
    for (long i = 0; i < n; i++) ok &= isfinite(v[i]) != 0;
    return ok;
}

int wf_fits_part_write_rows(fitsfile *f, int type, long ncols, LONGLONG row0, long nrows, void *data, int *status)
{
    if (*status) return *status;
    int bytepix;
    uint32_t flip;
    /* (asking also has cfitsio read the compression keywords a new HDU's header now holds) */
    const int compressed = fits_is_compressed_image(f, status);
    if (*status) return *status;
    if (compressed && ncols > 0 && own_rice(f, type, ncols, &bytepix, &flip)) {
        /* each row is a tile: its code into the COMPRESSED_DATA cell of table row (row + 1),
         * as cfitsio would have put it there */
        const size_t cap = wf_fits_rice_bound(ncols, bytepix);
        unsigned char *code = malloc(cap);
        if (!code) return *status = MEMORY_ALLOCATION;
        for (long r = 0; r < nrows && !*status; r++) {
            size_t len;
            const void *row = (const char *)data + (size_t)r * (size_t)ncols * (size_t)bytepix;
            if (wf_fits_rice_code(row, ncols, bytepix, flip, f->Fptr->rice_blocksize, code, cap, &len)) {
                *status = DATA_COMPRESSION_ERR;
                break;
            }
            fits_write_col(f, TBYTE, f->Fptr->cn_compressed, row0 + r + 1, 1, (LONGLONG)len, code, status);
        }
        free(code);
        own_tiles += nrows;
        return *status;
    }
    /* the part's q as fits_set_quantize_level stored it (0 as NO_QUANTIZE: exact floats);
     * cfitsio takes the requested level as each tile is compressed */
    const float q = f->Fptr->request_quantize_level;
    if (type != TFLOAT || !(q > 0) || q == CFITSIO_NO_QUANTIZE || ncols < 5)
        return fits_write_img(f, type, row0 * ncols + 1, (LONGLONG)nrows * ncols, data, status);
    float *scratch = malloc((size_t)ncols * sizeof *scratch);
    const int own = own_quantized(f, ncols);
    const size_t cap = wf_fits_rice_bound(ncols, 4);
    int *idata = own ? malloc((size_t)ncols * sizeof *idata) : NULL;
    unsigned char *code = own ? malloc(cap) : NULL;
    if (!scratch || (own && (!idata || !code))) {
        free(scratch);
        free(idata);
        free(code);
        return *status = MEMORY_ALLOCATION;
    }
    for (long r = 0; r < nrows && !*status; r++) {
        float *row = (float *)data + (size_t)r * (size_t)ncols;
        const double step = wf_fits_row_noise(row, ncols, scratch) / q;
        /* a negative level is cfitsio's absolute step; a row without noise to measure (a
         * constant or integer row) is left to cfitsio's own rules */
        const float level = step > 0 && isfinite(step) ? -(float)step : q;
        /* the tile as cfitsio's imcomp_compress_tile makes it, its Rice code ours: quantized
         * by cfitsio's own fits_quantize_float (dither row = tile + ZDITHER0 - 1), coded,
         * and its scale and zero in ZSCALE and ZZERO; rows with nonfinite pixels, or that do
         * not quantize (flag 0: cfitsio then stores them losslessly), go through cfitsio */
        const LONGLONG tile = row0 + r + 1;
        double bscale = 1.0, bzero = 0.0;
        int imin = 0, imax = 0, flag = 0;
        size_t len = 0;
        if (own && level < 0 && all_finite(row, ncols))
            flag = fits_quantize_float((long)tile + f->Fptr->dither_seed - 1, row, ncols, 1, 0, FLOATNULLVALUE,
                                       level, f->Fptr->quantize_method, idata, &bscale, &bzero, &imin, &imax);
        if (flag == 1 && !wf_fits_rice_code(idata, ncols, 4, 0, f->Fptr->rice_blocksize, code, cap, &len)) {
            fits_write_col(f, TBYTE, f->Fptr->cn_compressed, tile, 1, (LONGLONG)len, code, status);
            fits_write_col(f, TDOUBLE, f->Fptr->cn_zscale, tile, 1, 1, &bscale, status);
            fits_write_col(f, TDOUBLE, f->Fptr->cn_zzero, tile, 1, 1, &bzero, status);
            own_tiles++;
            continue;
        }
        /* cfitsio compresses a tile with quantize_level and refreshes that from the request
         * at times of its own (a tile late, observed): both are set */
        fits_set_quantize_level(f, level, status);
        f->Fptr->quantize_level = level;
        fits_write_img(f, TFLOAT, (row0 + r) * ncols + 1, ncols, row, status);
    }
    free(idata);
    free(code);
    int st = 0;
    fits_set_quantize_level(f, q, &st);
    f->Fptr->quantize_level = q;
    free(scratch);
    return *status;
}
