#define _GNU_SOURCE /* unshare(CLONE_NEWNS): a private tmpfs as a full disk */
/* wfisim's cfitsio disk driver and the data sums kept while writing: a product written out of
 * order through them has the bytes cfitsio's own file:// driver and its own DATASUM give. */
#include <fitsio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sched.h>
#include <signal.h>
#include <sys/mount.h>
#include <sys/resource.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include "sim/fits/fitsdisk.h"
#include "sim/fits/fitsout.h"
#include "tests/testutil.h"

enum { NX = 301, NY = 37, NR = 3, TILE = 5 }; /* odd sizes: 16-bit words straddle rows */

typedef struct pixels {
    float sci[NY][NX];
    uint32_t dq[NY][NX];
    uint16_t cube[NR][NY][NX];
} pixels;

static void fill(pixels *p)
{
    uint64_t x = 0x9e3779b97f4a7c15ull;
    for (int y = 0; y < NY; y++)
        for (int i = 0; i < NX; i++) {
            x ^= x << 13; x ^= x >> 7; x ^= x << 17;
            p->sci[y][i] = (float)((double)(x >> 11) / 9007199254740992.0 * 2e4 - 1e3);
            p->dq[y][i] = (uint32_t)(x >> 32);
            for (int r = 0; r < NR; r++) p->cube[r][y][i] = (uint16_t)(x >> (16 * r));
        }
    p->sci[3][4] = 0.0f;
    p->dq[5][6] = 0x80000000u; /* stored as a zero word */
}

static const char *tmp_path(char *buf, size_t cap, const char *name)
{
    snprintf(buf, cap, "%s/%s", wf_test_tmpdir(), name);
    return buf;
}

static void image(fitsfile *f, int bitpix, int naxis, const char *name, int *status)
{
    long naxes[3] = {NX, NY, NR};
    fits_create_img(f, bitpix, naxis, naxes, status);
    fits_write_key_str(f, "EXTNAME", name, NULL, status);
    ck_assert_int_eq(wf_fits_reserve_checksum(f, "test"), WF_OK);
}

/* n words of rows from y0 on (host order) through wf_fits_write32, from a copy: it turns
 * what it writes into the stored form in place */
static void write32(fitsfile *f, const void *rows, long y0, long n, uint32_t flip,
                    wf_fits_datasum *sum, int *status)
{
    uint32_t *copy = malloc((size_t)(n * NX) * 4);
    ck_assert_ptr_nonnull(copy);
    memcpy(copy, rows, (size_t)(n * NX) * 4);
    wf_fits_write32(f, (LONGLONG)y0 * NX, copy, (size_t)(n * NX), flip, sum, status);
    free(copy);
}

/* As the assembler writes an SCA: every header first, then tiles of rows out of order into
 * each image, a table last; known: DATASUMs summed while writing instead of read back;
 * fast: the 32-bit images written by wf_fits_write32 rather than fits_write_pix. */
static void write_product(fitsfile *f, const char *path, const pixels *p, int known, int fast)
{
    int status = 0;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    ck_assert_int_eq(wf_fits_reserve_checksum(f, "test"), WF_OK);
    image(f, FLOAT_IMG, 2, "SCI", &status);
    image(f, ULONG_IMG, 2, "DQ", &status);
    image(f, USHORT_IMG, 3, "CUBE", &status);
    ck_assert_int_eq(status, 0);
    wf_fits_datasum sum[5] = {{0}};
    for (int h = 1; h < 4; h++) sum[h].valid = known;
    const int order[] = {4, 0, 7, 2, 5, 1, 6, 3}; /* tiles of TILE rows, the last one short */
    for (int t = 0; t < 8; t++) {
        long y0 = (long)order[t] * TILE, n = y0 + TILE <= NY ? TILE : NY - y0;
        long first[2] = {1, y0 + 1};
        fits_movabs_hdu(f, 2, NULL, &status);
        if (fast) {
            write32(f, p->sci[y0], y0, n, 0, &sum[1], &status);
        } else {
            fits_write_pix(f, TFLOAT, first, n * NX, (void *)p->sci[y0], &status);
            wf_fits_datasum_add32(&sum[1], p->sci[y0], (size_t)(n * NX), 0);
        }
        fits_movabs_hdu(f, 3, NULL, &status);
        if (fast) {
            write32(f, p->dq[y0], y0, n, 0x80000000u, &sum[2], &status);
        } else {
            fits_write_pix(f, TUINT, first, n * NX, (void *)p->dq[y0], &status);
            wf_fits_datasum_add32(&sum[2], p->dq[y0], (size_t)(n * NX), 0x80000000u);
        }
        fits_movabs_hdu(f, 4, NULL, &status);
        for (int r = 0; r < NR; r++) {
            long fp[3] = {1, y0 + 1, r + 1}, lp[3] = {NX, y0 + n, r + 1};
            fits_write_subset(f, TUSHORT, fp, lp, (void *)p->cube[r][y0], &status);
            wf_fits_datasum_add16(&sum[3], p->cube[r][y0], (size_t)(n * NX),
                                  (uint64_t)NX * (uint64_t)(y0 + (long)NY * r), 0x8000);
        }
        ck_assert_int_eq(status, 0);
    }
    char *ttype[] = {"ID"}, *tform[] = {"J"};
    fits_create_tbl(f, BINARY_TBL, 3, 1, ttype, tform, NULL, "TABLE", &status);
    int ids[3] = {7, 8, 9};
    fits_write_col(f, TINT, 1, 1, 1, 3, ids, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(wf_fits_checksum_all(f, path, sum, 5), WF_OK);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

START_TEST(test_same_bytes_as_file_driver)
{
    wf_fitsdisk_uncached(_i == 0);
    pixels *p = malloc(sizeof *p);
    ck_assert_ptr_nonnull(p);
    fill(p);
    char a[4200], b[4200];
    tmp_path(a, sizeof a, "file_driver.fits");
    tmp_path(b, sizeof b, "wfdisk.fits");
    fitsfile *f;
    int status = 0;
    ck_assert_int_eq(fits_create_diskfile(&f, a, &status), 0);
    write_product(f, a, p, 0, 0); /* cfitsio's driver and writer, DATASUM read back by cfitsio */
    size_t la = 0;
    char *da = wf_test_slurp(a, &la);
    ck_assert_ptr_nonnull(da);
    ck_assert_uint_gt(la, (size_t)NX * NY * 14);
    /* ours, DATASUM summed while writing; then with wf_fits_write32, through cfitsio's
     * driver and through ours */
    for (int k = 0; k < 3; k++) {
        status = 0;
        if (k == 1) ck_assert_int_eq(fits_create_diskfile(&f, b, &status), 0);
        else ck_assert_int_eq(wf_fitsdisk_create(&f, b, &status), 0);
        write_product(f, b, p, 1, k > 0);
        size_t lb = 0;
        char *db = wf_test_slurp(b, &lb);
        ck_assert_ptr_nonnull(db);
        ck_assert_uint_eq(la, lb);
        ck_assert_msg(memcmp(da, db, la) == 0, "case %d: bytes differ from cfitsio's", k);
        ck_assert_int_eq(wf_fits_verify_checksums(b, 5), WF_OK);
        free(db);
        ck_assert_int_eq(unlink(b), 0);
    }
    free(da);
    free(p);
}
END_TEST

/* Tiles of an image several times the driver's buffer, each tile larger than the size it
 * writes straight to the file, out of order through wf_fits_write32 and our driver: the
 * bytes of fits_write_pix through cfitsio's driver. And what it refuses: a stored type
 * other than the words' (a 16-bit image, a float image as TUINT, an unsigned one as
 * TFLOAT) and elements outside the image, leaving the file as it was. */
START_TEST(test_write32_large_tiles)
{
    wf_fitsdisk_uncached(_i == 0);
    enum { W = 1031, H = 700, T = 97 }; /* a tile: 400 kB; the image: 2.9 MB */
    float *img = malloc((size_t)W * H * sizeof *img), *copy = malloc((size_t)W * T * sizeof *img);
    ck_assert_ptr_nonnull(img);
    ck_assert_ptr_nonnull(copy);
    uint64_t x = 0x2545f4914f6cdd1dull;
    for (size_t i = 0; i < (size_t)W * H; i++) {
        x ^= x << 13; x ^= x >> 7; x ^= x << 17;
        img[i] = (float)((double)(x >> 11) / 9007199254740992.0 * 1e5 - 5e3);
    }
    char a[4200], b[4200];
    tmp_path(a, sizeof a, "large_ref.fits");
    tmp_path(b, sizeof b, "large_write32.fits");
    long naxes[2] = {W, H};
    const int order[] = {3, 6, 0, 5, 1, 7, 2, 4}; /* 8 tiles, the last one short */
    for (int k = 0; k < 2; k++) {
        fitsfile *f;
        int status = 0;
        if (k == 0) ck_assert_int_eq(fits_create_diskfile(&f, a, &status), 0);
        else ck_assert_int_eq(wf_fitsdisk_create(&f, b, &status), 0);
        fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
        fits_create_img(f, USHORT_IMG, 2, naxes, &status);
        fits_create_img(f, ULONG_IMG, 2, naxes, &status);
        fits_movabs_hdu(f, 1, NULL, &status);
        ck_assert_int_eq(status, 0);
        wf_fits_datasum sum = {0, 0, 1};
        for (int t = 0; t < 8; t++) {
            long y0 = (long)order[t] * T, n = y0 + T <= H ? T : H - y0;
            if (k == 0) {
                long first[2] = {1, y0 + 1};
                fits_write_pix(f, TFLOAT, first, n * W, img + y0 * W, &status);
            } else {
                memcpy(copy, img + y0 * W, (size_t)(n * W) * sizeof *img);
                wf_fits_write32(f, (LONGLONG)y0 * W, copy, (size_t)(n * W), 0, &sum, &status);
                /* the words handed in now hold what the file holds: big-endian */
                const unsigned char *be = (const unsigned char *)copy;
                uint32_t w0;
                memcpy(&w0, img + y0 * W, 4);
                ck_assert_uint_eq((uint32_t)be[0] << 24 | (uint32_t)be[1] << 16 |
                                  (uint32_t)be[2] << 8 | be[3], w0);
            }
            ck_assert_int_eq(status, 0);
        }
        if (k == 1) {
            wf_fits_datasum want = {0, 0, 1};
            wf_fits_datasum_add32(&want, img, (size_t)W * H, 0);
            ck_assert(sum.hi == want.hi && sum.lo == want.lo);
            uint32_t one = 1;
            status = 0;
            ck_assert_int_eq(wf_fits_write32(f, (LONGLONG)W * H - 1, &one, 2, 0, &sum, &status),
                             BAD_ELEM_NUM);
            status = 0;
            ck_assert_int_eq(wf_fits_write32(f, -1, &one, 1, 0, &sum, &status), BAD_ELEM_NUM);
            status = 0;
            ck_assert_int_eq(wf_fits_write32(f, 0, &one, 1, 0x80000000u, &sum, &status),
                             BAD_DATATYPE);
            for (int h = 2; h <= 3; h++) {
                status = 0;
                fits_movabs_hdu(f, h, NULL, &status);
                ck_assert_int_eq(wf_fits_write32(f, 0, &one, 1, 0, &sum, &status), BAD_DATATYPE);
            }
            ck_assert(sum.hi == want.hi && sum.lo == want.lo); /* a refused call adds nothing */
            status = 0;
            fits_clear_errmsg();
        }
        fits_close_file(f, &status);
        ck_assert_int_eq(status, 0);
    }
    size_t la = 0, lb = 0;
    char *da = wf_test_slurp(a, &la), *db = wf_test_slurp(b, &lb);
    ck_assert_ptr_nonnull(da);
    ck_assert_ptr_nonnull(db);
    ck_assert_uint_eq(la, lb);
    ck_assert(memcmp(da, db, la) == 0);
    free(da);
    free(db);
    free(img);
    free(copy);
}
END_TEST

/* Rows written one at a time in a scrambled order into an image larger than cfitsio's
 * buffers: records are evicted and read back half written, some from holes, some after
 * their data reached the disk. Read back while open, and the bytes after closing, must be
 * those of cfitsio's own driver. */
static void scrambled_rows(fitsfile *f, float *img, int ny, int check)
{
    int status = 0;
    long naxes[2] = {NX, ny};
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status); /* a second image: the first is a gap */
    fits_movabs_hdu(f, 1, NULL, &status);
    for (int k = 0; k < ny; k++) {
        long y = (long)k * 7919 % ny; /* 7919 is prime, ny not a multiple: every row once */
        long first[2] = {1, y + 1};
        fits_write_pix(f, TFLOAT, first, NX, img + y * NX, &status);
    }
    ck_assert_int_eq(status, 0);
    if (check) {
        float *back = malloc((size_t)NX * (size_t)ny * sizeof *back);
        int anynul = 0;
        fits_read_img(f, TFLOAT, 1, (LONGLONG)NX * ny, NULL, back, &anynul, &status);
        ck_assert_int_eq(status, 0);
        ck_assert(memcmp(back, img, (size_t)NX * (size_t)ny * sizeof *back) == 0);
        free(back);
    }
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

START_TEST(test_scrambled_rows)
{
    wf_fitsdisk_uncached(_i == 0);
    enum { NYS = 2000 }; /* 2.4 MB: far more than cfitsio's forty 2880-byte buffers */
    float *img = malloc((size_t)NX * NYS * sizeof *img);
    ck_assert_ptr_nonnull(img);
    for (size_t i = 0; i < (size_t)NX * NYS; i++) img[i] = (float)(i % 9973) + 0.5f;
    char a[4200], b[4200];
    tmp_path(a, sizeof a, "rows_file_driver.fits");
    tmp_path(b, sizeof b, "rows_wfdisk.fits");
    fitsfile *f;
    int status = 0;
    ck_assert_int_eq(fits_create_diskfile(&f, a, &status), 0);
    scrambled_rows(f, img, NYS, 0);
    ck_assert_int_eq(wf_fitsdisk_create(&f, b, &status), 0);
    scrambled_rows(f, img, NYS, 1);
    size_t la = 0, lb = 0;
    char *da = wf_test_slurp(a, &la), *db = wf_test_slurp(b, &lb);
    ck_assert_ptr_nonnull(da);
    ck_assert_ptr_nonnull(db);
    ck_assert_uint_eq(la, lb);
    ck_assert(memcmp(da, db, la) == 0);
    free(da);
    free(db);
    free(img);
}
END_TEST

/* The zero records cfitsio writes before a header placed after unwritten data become a
 * hole: the file is as long as with zeros written, and reads back the same zeros. */
START_TEST(test_gap_is_a_hole)
{
    wf_fitsdisk_uncached(_i == 0);
    char path[4200];
    tmp_path(path, sizeof path, "holes.fits");
    fitsfile *f;
    int status = 0;
    ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
    long naxes[2] = {2048, 2048}; /* 16 MiB of float */
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    fits_flush_file(f, &status);
    ck_assert_int_eq(status, 0);
    struct stat sb;
    ck_assert_int_eq(stat(path, &sb), 0);
    ck_assert_int_ge((long long)sb.st_size, 2880LL * 2 + 2048LL * 2048 * 4);
    ck_assert_int_lt((long long)sb.st_blocks * 512, (long long)sb.st_size / 4);
    float v[4] = {1, 2, 3, 4};
    fits_movabs_hdu(f, 1, NULL, &status);
    fits_write_img(f, TFLOAT, 2048LL * 2048 - 3, 4, v, &status); /* the last pixels only */
    float back[8];
    int anynul = 0;
    fits_read_img(f, TFLOAT, 2048LL * 2048 - 7, 8, NULL, back, &anynul, &status);
    ck_assert_int_eq(status, 0);
    for (int i = 0; i < 4; i++) ck_assert(back[i] == 0.0f && back[4 + i] == v[i]);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(fits_open_diskfile(&f, path, READONLY, &status), 0);
    fits_movabs_hdu(f, 2, NULL, &status);
    fits_read_img(f, TFLOAT, 1000, 8, NULL, back, &anynul, &status);
    ck_assert_int_eq(status, 0);
    for (int i = 0; i < 8; i++) ck_assert(back[i] == 0.0f);
    fits_close_file(f, &status);
}
END_TEST

/* Names are taken literally; an existing file is never replaced; slots are reused. */
START_TEST(test_names_and_slots)
{
    char path[4200];
    tmp_path(path, sizeof path, "odd[1](x)!name.fits");
    fitsfile *f;
    int status = 0;
    for (int i = 0; i < 200; i++) { /* more than the driver's slots, one open at a time */
        unlink(path);
        ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
        fits_create_img(f, BYTE_IMG, 0, NULL, &status);
        fits_write_key_lng(f, "N", i, NULL, &status);
        fits_close_file(f, &status);
        ck_assert_int_eq(status, 0);
    }
    long n = -1;
    ck_assert_int_eq(fits_open_diskfile(&f, path, READONLY, &status), 0);
    fits_read_key_lng(f, "N", &n, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(n, 199);
    ck_assert_int_ne(wf_fitsdisk_create(&f, path, &status), 0);
    ck_assert_ptr_null(f);
    status = 0;
    fits_clear_errmsg();
    ck_assert_int_eq(fits_open_diskfile(&f, path, READONLY, &status), 0);
    fits_read_key_lng(f, "N", &n, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(n, 199);
}
END_TEST

/* Writes of every size at every offset, overlapping, in random order, with reads between
 * them while the file is open: with the page edges held back for the uncached path, the
 * latest bytes must still win, and the file must be cfitsio's own driver's. */
static void random_writes(fitsfile *f, float *model, const float *vals, int check)
{
    enum { W = 1031, H = 700 };
    int status = 0;
    long naxes[2] = {W, H};
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status); /* the first image is then a gap */
    fits_movabs_hdu(f, 1, NULL, &status);
    ck_assert_int_eq(status, 0);
    const LONGLONG npix = (LONGLONG)W * H;
    uint64_t x = 0x853c49e6748fea9bull;
    float *back = malloc(200000 * sizeof *back);
    ck_assert_ptr_nonnull(back);
    for (int k = 0; k < 400; k++) {
        x ^= x << 13; x ^= x >> 7; x ^= x << 17;
        LONGLONG first = (LONGLONG)(x % (uint64_t)npix), n;
        int size_class = (int)(x >> 40) % 4; /* a few pixels, a row or two, a page, a tile */
        LONGLONG span = size_class == 0 ? 7 : size_class == 1 ? 2 * W : size_class == 2 ? 1500 : 200000;
        n = 1 + (LONGLONG)((x >> 20) % (uint64_t)span);
        if (first + n > npix) n = npix - first;
        const float *v = vals + (k * 7919) % 100000; /* vals holds 300000 */
        fits_write_img(f, TFLOAT, first + 1, n, (float *)v, &status);
        ck_assert_int_eq(status, 0);
        if (model) memcpy(model + first, v, (size_t)n * sizeof *v);
        if (check && k % 16 == 5) {
            LONGLONG r = (LONGLONG)((x >> 8) % (uint64_t)npix), m = npix - r < 150000 ? npix - r : 150000;
            int anynul = 0;
            fits_read_img(f, TFLOAT, r + 1, m, NULL, back, &anynul, &status);
            ck_assert_int_eq(status, 0);
            ck_assert(memcmp(back, model + r, (size_t)m * sizeof *back) == 0);
        }
    }
    free(back);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
}

START_TEST(test_random_writes)
{
    wf_fitsdisk_uncached(_i == 0);
    float *vals = malloc(300000 * sizeof *vals), *model = calloc((size_t)1031 * 700, sizeof *model);
    ck_assert_ptr_nonnull(vals);
    ck_assert_ptr_nonnull(model);
    for (int i = 0; i < 300000; i++) vals[i] = (float)i * 0.25f + 1.0f;
    char a[4200], b[4200];
    tmp_path(a, sizeof a, "random_file_driver.fits");
    tmp_path(b, sizeof b, "random_wfdisk.fits");
    fitsfile *f;
    int status = 0;
    ck_assert_int_eq(fits_create_diskfile(&f, a, &status), 0);
    random_writes(f, NULL, vals, 0);
    ck_assert_int_eq(wf_fitsdisk_create(&f, b, &status), 0);
    random_writes(f, model, vals, 1);
    size_t la = 0, lb = 0;
    char *da = wf_test_slurp(a, &la), *db = wf_test_slurp(b, &lb);
    ck_assert_ptr_nonnull(da);
    ck_assert_ptr_nonnull(db);
    ck_assert_uint_eq(la, lb);
    ck_assert(memcmp(da, db, la) == 0);
    free(da);
    free(db);
    free(vals);
    free(model);
}
END_TEST

/* Where the file system states how (statx), a large product's pixels go past the page
 * cache; wf_fitsdisk_uncached(0) sends every byte through it. */
START_TEST(test_uncached_path_taken)
{
    char probe[4200];
    tmp_path(probe, sizeof probe, "probe");
    FILE *pf = fopen(probe, "w"); /* only regular files state it */
    ck_assert_ptr_nonnull(pf);
    fclose(pf);
    struct statx sx;
    int stated = statx(AT_FDCWD, probe, 0, STATX_DIOALIGN, &sx) == 0 &&
                 (sx.stx_mask & STATX_DIOALIGN) && sx.stx_dio_offset_align;
    unlink(probe);
    if (!stated) WF_SKIP("the test directory's file system states no direct-I/O alignment");
    enum { W = 2048, H = 512 }; /* 4 MiB */
    float *img = malloc((size_t)W * H * sizeof *img);
    ck_assert_ptr_nonnull(img);
    for (size_t i = 0; i < (size_t)W * H; i++) img[i] = (float)(i % 4099) - 7.5f;
    for (int on = 1; on >= 0; on--) {
        char path[4200];
        tmp_path(path, sizeof path, on ? "uncached_on.fits" : "uncached_off.fits");
        wf_fitsdisk_uncached(on);
        long long u0, c0, u1, c1;
        wf_fitsdisk_written(&u0, &c0);
        fitsfile *f;
        int status = 0;
        long naxes[2] = {W, H};
        ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
        fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
        for (int y = 0; y < H; y += 64) {
            long first[2] = {1, y + 1};
            fits_write_pix(f, TFLOAT, first, 64L * W, img + (size_t)y * W, &status);
        }
        fits_close_file(f, &status);
        ck_assert_int_eq(status, 0);
        wf_fitsdisk_written(&u1, &c1);
        long long bytes = (long long)W * H * 4;
        if (on) {
            ck_assert_int_ge(u1 - u0, bytes * 9 / 10);
            ck_assert_int_lt(c1 - c0, bytes / 10);
        } else {
            ck_assert_int_eq(u1 - u0, 0);
            ck_assert_int_ge(c1 - c0, bytes);
        }
        fitsfile *g;
        float v = 0;
        int anynul = 0;
        ck_assert_int_eq(fits_open_diskfile(&g, path, READONLY, &status), 0);
        fits_read_img(g, TFLOAT, (LONGLONG)W * H - 5, 1, NULL, &v, &anynul, &status);
        fits_close_file(g, &status);
        ck_assert_int_eq(status, 0);
        ck_assert(v == img[(size_t)W * H - 6]);
    }
    free(img);
}
END_TEST

/* The assembler's pattern: a tile of resultants written plane by plane, read back (its
 * saturation came later), its fit written to another HDU. cfitsio reloads the cube's records
 * one by one and writes its dirty ones out in between; the driver reads no more from the
 * file than the rows asked for (once the data, plus a record at each plane's edges and read
 * ahead), where a read cache dropped by every write refilled a megabyte per record. */
START_TEST(test_read_back_bounded)
{
    enum { W = 1024, H = 256, R = 6, T = 32 };
    static uint16_t cube[R][T][W], back[R][T][W];
    static float sci[T][W];
    char path[4200];
    tmp_path(path, sizeof path, _i ? "readback_on.fits" : "readback_off.fits");
    wf_fitsdisk_uncached(_i);
    fitsfile *f;
    int status = 0, anynul = 0;
    long img[2] = {W, H}, naxes[3] = {W, H, R};
    ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_create_img(f, FLOAT_IMG, 2, img, &status);
    fits_create_img(f, USHORT_IMG, 3, naxes, &status);
    ck_assert_int_eq(status, 0);
    long long before = wf_fitsdisk_read_back();
    for (int y0 = 0; y0 < H; y0 += T) {
        for (int r = 0; r < R; r++)
            for (int y = 0; y < T; y++)
                for (int x = 0; x < W; x++) cube[r][y][x] = (uint16_t)(x * 7 + (y0 + y) * 131 + r * 4099);
        long fp[3] = {1, y0 + 1, 1}, lp[3] = {W, y0 + T, R}, inc[3] = {1, 1, 1};
        fits_movabs_hdu(f, 3, NULL, &status);
        fits_write_subset(f, TUSHORT, fp, lp, cube, &status);
        fits_read_subset(f, TUSHORT, fp, lp, inc, NULL, back, &anynul, &status);
        ck_assert_int_eq(status, 0);
        ck_assert(memcmp(cube, back, sizeof cube) == 0);
        for (int y = 0; y < T; y++)
            for (int x = 0; x < W; x++) sci[y][x] = (float)cube[R - 1][y][x] - cube[0][y][x];
        fits_movabs_hdu(f, 2, NULL, &status);
        fits_write_img(f, TFLOAT, (LONGLONG)y0 * W + 1, (LONGLONG)T * W, sci, &status);
        ck_assert_int_eq(status, 0);
    }
    long long read = wf_fitsdisk_read_back() - before;
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    long long cube_bytes = (long long)W * H * R * 2;
    ck_assert_msg(read <= cube_bytes + cube_bytes / 4, "read back %lld bytes for a %lld-byte cube", read,
                  cube_bytes);
    fitsfile *g; /* and the file holds the last tile */
    ck_assert_int_eq(fits_open_diskfile(&g, path, READONLY, &status), 0);
    fits_movabs_hdu(g, 3, NULL, &status);
    long fp[3] = {1, H - T + 1, 1}, lp[3] = {W, H, R}, inc[3] = {1, 1, 1};
    fits_read_subset(g, TUSHORT, fp, lp, inc, NULL, back, &anynul, &status);
    fits_close_file(g, &status);
    ck_assert_int_eq(status, 0);
    ck_assert(memcmp(cube, back, sizeof cube) == 0);
}
END_TEST

/* A write the system refuses (here the file-size limit, as a full disk would) fails the
 * cfitsio call or the close, with the system's reason on cfitsio's error stack. */
START_TEST(test_write_failure_reported)
{
    char path[4200];
    tmp_path(path, sizeof path, "limited.fits");
    signal(SIGXFSZ, SIG_IGN);
    struct rlimit rl = {1 << 20, 1 << 20}; /* Check runs each test in its own process */
    ck_assert_int_eq(setrlimit(RLIMIT_FSIZE, &rl), 0);
    fitsfile *f;
    int status = 0, close_status = 0;
    ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
    long naxes[2] = {1024, 1024};
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    static float row[1024 * 16];
    for (int i = 0; i < 1024 * 16; i++) row[i] = (float)i;
    for (long y = 0; y < 1024 && !status; y += 16) fits_write_img(f, TFLOAT, y * 1024 + 1, 1024 * 16, row, &status);
    int write_status = status;
    char msg[FLEN_ERRMSG], all[2048] = "";
    while (fits_read_errmsg(msg)) strncat(all, msg, sizeof all - strlen(all) - 1);
    fits_close_file(f, &close_status);
    while (fits_read_errmsg(msg)) strncat(all, msg, sizeof all - strlen(all) - 1);
    ck_assert_msg(write_status != 0 || close_status != 0, "a 4 MiB image written under a 1 MiB limit");
    ck_assert_msg(strstr(all, "File too large") != NULL, "reason missing from: %s", all);
}
END_TEST

/* A full disk at the buffer's last flush: cfitsio ignores what a flush returns, and extending
 * a file with a hole still works on a full disk, so only a failure the driver keeps makes the
 * close fail. A private 256 KiB tmpfs (a mount namespace of this test's own process, gone
 * with it) is the full disk; without the privilege for one the test is skipped. */
START_TEST(test_full_disk_at_the_close)
{
    char dir[4200], path[4300];
    tmp_path(dir, sizeof dir, "full");
    ck_assert_int_eq(mkdir(dir, 0755), 0);
    const char *fork_mode = getenv("CK_FORK");
    if (fork_mode && !strcmp(fork_mode, "no")) /* the namespace would outlive the test */
        WF_SKIP("needs Check's fork mode for a private mount namespace");
    if (unshare(CLONE_NEWNS) != 0 || mount("none", "/", NULL, MS_REC | MS_PRIVATE, NULL) != 0 ||
        mount("tmpfs", dir, "tmpfs", 0, "size=256k") != 0)
        WF_SKIP("a private tmpfs needs root (CAP_SYS_ADMIN)");
    snprintf(path, sizeof path, "%s/full.fits", dir);
    fitsfile *f;
    int status = 0, close_status = 0;
    ck_assert_int_eq(wf_fitsdisk_create(&f, path, &status), 0);
    long naxes[2] = {256, 512}; /* 512 KiB of float: more than the disk, less than the buffer */
    fits_create_img(f, FLOAT_IMG, 2, naxes, &status);
    static float pix[256 * 512];
    for (int i = 0; i < 256 * 512; i++) pix[i] = (float)i + 1.0f;
    fits_write_img(f, TFLOAT, 1, 256 * 512, pix, &status);
    ck_assert_int_eq(status, 0); /* still in the driver's buffer */
    fits_flush_buffer(f, 0, &status); /* the write fails here, and cfitsio drops its status */
    char msg[FLEN_ERRMSG], all[2048] = "";
    fits_close_file(f, &close_status);
    while (fits_read_errmsg(msg)) strncat(all, msg, sizeof all - strlen(all) - 1);
    ck_assert_msg(close_status != 0, "512 KiB closed without error on a 256 KiB disk");
    ck_assert_msg(strstr(all, "No space left on device") != NULL, "reason missing from: %s", all);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("fitsdisk");
    TCase *tc = tcase_create("core");
    tcase_add_loop_test(tc, test_same_bytes_as_file_driver, 0, 2);
    tcase_add_loop_test(tc, test_write32_large_tiles, 0, 2);
    tcase_add_loop_test(tc, test_gap_is_a_hole, 0, 2);
    tcase_add_loop_test(tc, test_scrambled_rows, 0, 2);
    tcase_add_loop_test(tc, test_random_writes, 0, 2);
    tcase_add_test(tc, test_uncached_path_taken);
    tcase_add_loop_test(tc, test_read_back_bounded, 0, 2);
    tcase_add_test(tc, test_names_and_slots);
    tcase_add_test(tc, test_write_failure_reported);
    tcase_add_test(tc, test_full_disk_at_the_close);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
