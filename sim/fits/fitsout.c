#include "sim/fits/fitsout.h"
#include "sim/fits/fitsdisk.h"
#include "hal/simd.h"
#include "hal/file.h"

#include <fitsio2.h>

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define CHECKSUM_ZERO "0000000000000000"
#define CHECKSUM_COMMENT "HDU checksum"
#define DATASUM_COMMENT "data unit checksum"
#define FITS_BLOCK 2880LL

wf_status wf_fits_error(int status, const char *path, const char *doing)
{
    if (status == 0) return WF_OK;
    char text[FLEN_STATUS] = "", stack[512] = "", msg[FLEN_ERRMSG];
    fits_get_errstatus(status, text);
    size_t len = 0;
    /* The stack holds cfitsio's own context (which keyword, which file call); the oldest
     * entries are the most specific, so keep them first and cut at the buffer's end. */
    while (fits_read_errmsg(msg)) {
        int n = snprintf(stack + len, sizeof stack - len, "%s%s", len ? "; " : "", msg);
        if (n < 0 || (size_t)n >= sizeof stack - len) {
            len = sizeof stack - 1;
            continue; /* drain the rest so the next error starts clean */
        }
        len += (size_t)n;
    }
    fits_clear_errmsg();
    if (len)
        return wf_error(WF_ERR_IO, "%s: %s: cfitsio error %d, %s (%s)", path, doing, status, text,
                        stack);
    return wf_error(WF_ERR_IO, "%s: %s: cfitsio error %d, %s", path, doing, status, text);
}

wf_status wf_fits_reserve_checksum(fitsfile *f, const char *path)
{
    int status = 0;
    fits_write_key_str(f, "CHECKSUM", CHECKSUM_ZERO, CHECKSUM_COMMENT, &status);
    fits_write_key_str(f, "DATASUM", "0", DATASUM_COMMENT, &status);
    return wf_fits_error(status, path, "reserving CHECKSUM/DATASUM");
}

/* Carries fold back in, each half into the other: the 32-bit one's complement sum. */
static unsigned long fold(uint64_t hi, uint64_t lo)
{
    while ((hi >> 16) | (lo >> 16)) {
        uint64_t ch = hi >> 16, cl = lo >> 16;
        hi = (hi & 0xffff) + cl;
        lo = (lo & 0xffff) + ch;
    }
    return (unsigned long)(hi << 16 | lo);
}

unsigned long wf_fits_datasum_value(const wf_fits_datasum *s) { return fold(s->hi, s->lo); }

void wf_fits_datasum_add_bytes(wf_fits_datasum *s, const unsigned char *bytes, size_t n, uint64_t offset)
{
    /* byte k of a word (k = its offset mod 4) is bits 31-24, 23-16, 15-8, 7-0: the upper or
     * lower byte of the word's upper or lower half */
    uint64_t b[4] = {0, 0, 0, 0};
    size_t i = 0;
    for (; i < n && (offset + i) % 4; i++) b[(offset + i) % 4] += bytes[i];
    uint64_t w0 = 0, w1 = 0, w2 = 0, w3 = 0;
    for (; i + 4 <= n; i += 4) {
        w0 += bytes[i];
        w1 += bytes[i + 1];
        w2 += bytes[i + 2];
        w3 += bytes[i + 3];
    }
    b[0] += w0, b[1] += w1, b[2] += w2, b[3] += w3;
    for (; i < n; i++) b[(offset + i) % 4] += bytes[i];
    s->hi += (b[0] << 8) + b[1];
    s->lo += (b[2] << 8) + b[3];
}

void wf_fits_datasum_add32(wf_fits_datasum *s, const void *values, size_t n, uint32_t flip)
{
    const unsigned char *p = values;
    /* 32-bit partial sums over blocks of 65536 words cannot overflow (65536 x 0xffff < 2^32)
     * and vectorise; the 64-bit totals take each block's */
    for (size_t b = 0; b < n; b += 65536) {
        size_t m = n - b < 65536 ? n - b : 65536;
        uint32_t hi = 0, lo = 0;
        for (size_t i = 0; i < m; i++) {
            uint32_t w;
            memcpy(&w, p + 4 * (b + i), 4);
            w ^= flip;
            hi += w >> 16;
            lo += w & 0xffff;
        }
        s->hi += hi;
        s->lo += lo;
    }
}

/* The n words of w, flipped, put in big-endian order in place; hl = the sums of their upper
 * and lower halves (n <= 65536: 32 bits cannot overflow). The swap is spelt in shifts, which
 * vectorise on any x86-64 (a byte swap builtin would stay scalar). */
WF_CLONES static void big_endian32(uint32_t *w, size_t n, uint32_t flip, uint32_t hl[2])
{
    uint32_t hi = 0, lo = 0;
    for (size_t i = 0; i < n; i++) {
        uint32_t v = w[i] ^ flip;
        hi += v >> 16;
        lo += v & 0xffff;
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
        w[i] = v;
#else
        w[i] = v << 24 | (v << 8 & 0xff0000u) | (v >> 8 & 0xff00u) | v >> 24;
#endif
    }
    hl[0] = hi;
    hl[1] = lo;
}

int wf_fits_write32(fitsfile *f, LONGLONG first, void *values, size_t n, uint32_t flip,
                    wf_fits_datasum *sum, int *status)
{
    if (*status > 0) return *status;
    int bitpix = 0, equiv = 0, naxis = 0;
    long naxes[3] = {0, 0, 0};
    LONGLONG head, data, end;
    if (fits_get_img_type(f, &bitpix, status) || fits_get_img_equivtype(f, &equiv, status) ||
        fits_get_img_dim(f, &naxis, status) || fits_get_img_size(f, 3, naxes, status) ||
        fits_get_hduaddrll(f, &head, &data, &end, status))
        return *status;
    if (!(flip == 0 ? (bitpix == FLOAT_IMG || bitpix == LONG_IMG) && equiv == bitpix
                    : flip == 0x80000000u && bitpix == LONG_IMG && equiv == ULONG_IMG)) {
        ffpmsg("wf_fits_write32: the image's stored type is not that of the words written");
        return *status = BAD_DATATYPE;
    }
    LONGLONG count = naxis ? 1 : 0;
    for (int i = 0; i < naxis && i < 3; i++) count *= naxes[i];
    if (first < 0 || naxis > 3 || (LONGLONG)n > count - first) {
        ffpmsg("wf_fits_write32: elements beyond the image");
        return *status = BAD_ELEM_NUM;
    }
    uint32_t *w = values;
    for (size_t c = 0; c < n; c += 65536) {
        uint32_t hl[2];
        big_endian32(w + c, n - c < 65536 ? n - c : 65536, flip, hl);
        sum->hi += hl[0];
        sum->lo += hl[1];
    }
    /* ffpbyt hands the whole records of a large write straight to the file driver */
    if (ffmbyt(f, data + 4 * first, IGNORE_EOF, status)) return *status;
    return ffpbyt(f, (LONGLONG)n * 4, values, status);
}

void wf_fits_datasum_add16(wf_fits_datasum *s, const uint16_t *values, size_t n, uint64_t first,
                           uint16_t flip)
{
    uint64_t even = 0, odd = 0;
    size_t i = 0;
    while (i + 1 < n) { /* 32-bit partial sums, as in wf_fits_datasum_add32 */
        size_t end = n - i > 131072 ? i + 131072 : n - ((n - i) & 1);
        uint32_t e = 0, o = 0;
        for (; i < end; i += 2) {
            e += (uint16_t)(values[i] ^ flip);
            o += (uint16_t)(values[i + 1] ^ flip);
        }
        even += e;
        odd += o;
    }
    if (i < n) even += (uint16_t)(values[i] ^ flip);
    /* element i of the run is element first + i of the data unit */
    if (first & 1) { s->hi += odd; s->lo += even; }
    else { s->hi += even; s->lo += odd; }
}

/* sum += the FITS checksum (32-bit one's complement, big-endian words) of the header bytes
 * [head, data) of the file at path, as cfitsio has flushed them. */
static wf_status header_sum(const char *path, LONGLONG head, LONGLONG data, unsigned long *sum)
{
    FILE *in = fopen(path, "rb");
    if (!in) return wf_error(WF_ERR_IO, "%s: reopening for the header checksum: %s", path, strerror(errno));
    unsigned char block[FITS_BLOCK];
    uint64_t hi = *sum >> 16, lo = *sum & 0xffff;
    wf_status st = WF_OK;
    if (fseeko(in, (off_t)head, SEEK_SET) != 0) st = wf_error(WF_ERR_IO, "%s: seeking to a header: %s", path, strerror(errno));
    for (LONGLONG at = head; !st && at < data; at += FITS_BLOCK) {
        if (fread(block, 1, sizeof block, in) != sizeof block) {
            st = wf_error(WF_ERR_IO, "%s: reading a header back for its checksum", path);
            break;
        }
        for (size_t i = 0; i < sizeof block; i += 4) {
            hi += (uint64_t)block[i] << 8 | block[i + 1];
            lo += (uint64_t)block[i + 2] << 8 | block[i + 3];
        }
    }
    fclose(in);
    *sum = fold(hi, lo);
    return st;
}

static wf_status checksum_hdu(fitsfile *f, const char *path, const wf_fits_datasum *known)
{
    int status = 0;
    if (known) {
        /* what fits_write_chksum does before it reads the data: the header's end found
         * again and the data fill written (cfitsio internals, fitsio2.h) */
        ffrdef(f, &status);
        ffpdfl(f, &status);
        char v[24];
        snprintf(v, sizeof v, "%lu", fold(known->hi, known->lo));
        fits_modify_key_str(f, "DATASUM", v, DATASUM_COMMENT, &status);
    } else {
        /* fits_write_chksum does what only cfitsio internals can (close the header, write
         * the data fill) and gets DATASUM right, reading the data once; then the dated
         * comments are replaced and CHECKSUM recomputed over the header as it finally stands
         * plus DATASUM (fits_get_chksum would read the data a second time). */
        fits_write_chksum(f, &status);
        fits_modify_comment(f, "DATASUM", DATASUM_COMMENT, &status);
    }
    fits_modify_comment(f, "CHECKSUM", CHECKSUM_COMMENT, &status);
    fits_modify_key_str(f, "CHECKSUM", CHECKSUM_ZERO, "&", &status);
    char value[FLEN_VALUE] = "";
    fits_read_key_str(f, "DATASUM", value, NULL, &status);
    LONGLONG head = 0, data = 0, end = 0;
    fits_get_hduaddrll(f, &head, &data, &end, &status);
    fits_flush_buffer(f, 0, &status);
    if (status) return wf_fits_error(status, path, "writing DATASUM and flushing the header");
    char *stop = NULL;
    unsigned long sum = strtoul(value, &stop, 10);
    if (stop == value || *stop) return wf_error(WF_ERR_INTERNAL, "%s: DATASUM '%s' is not a number", path, value);
    wf_status st = header_sum(path, head, data, &sum);
    if (st) return st;
    char ascii[17];
    fits_encode_chksum(sum, 1, ascii);
    fits_modify_key_str(f, "CHECKSUM", ascii, "&", &status);
    return wf_fits_error(status, path, "writing CHECKSUM");
}

wf_status wf_fits_checksum_all(fitsfile *f, const char *path, const wf_fits_datasum *sums, int nsums)
{
    int status = 0, nhdu = 0, current = 0;
    /* fits_get_num_hdus leaves out a just-created HDU that has no data written yet (an
     * empty table), so the current HDU number bounds the count from below. */
    fits_get_hdu_num(f, &current);
    if (fits_get_num_hdus(f, &nhdu, &status))
        return wf_fits_error(status, path, "counting HDUs");
    if (current > nhdu) nhdu = current;
    for (int i = 1; i <= nhdu; i++) {
        if (fits_movabs_hdu(f, i, NULL, &status))
            return wf_fits_error(status, path, "moving to an HDU for its checksum");
        const wf_fits_datasum *known = i <= nsums && sums[i - 1].valid ? &sums[i - 1] : NULL;
        wf_status st = checksum_hdu(f, path, known);
        if (st) return st;
    }
    return WF_OK;
}

static wf_status verify_open(fitsfile *f, const char *path, int expect)
{
    int status = 0, nhdu = 0;
    if (fits_get_num_hdus(f, &nhdu, &status)) return wf_fits_error(status, path, "counting sections");
    if (nhdu < 1) return wf_error(WF_ERR_CORRUPT, "%s: no section", path);
    struct stat sb;
    if (stat(path, &sb) != 0) return wf_error(WF_ERR_IO, "%s: %s", path, strerror(errno));
    LONGLONG head = 0, data = 0, end = 0;
    if (fits_movabs_hdu(f, nhdu, NULL, &status) || fits_get_hduaddrll(f, &head, &data, &end, &status))
        return wf_fits_error(status, path, "locating the last section");
    /* The whole-file test comes before the checksums: on a truncated file those would fail
     * with a cfitsio read error that says less than this. */
    end = (end + FITS_BLOCK - 1) / FITS_BLOCK * FITS_BLOCK;
    LONGLONG size = (LONGLONG)sb.st_size;
    if (end > size)
        return wf_error(WF_ERR_CORRUPT, "%s: section %d ends at byte %lld but the file has %lld: truncated",
                        path, nhdu, (long long)end, (long long)size);
    if (end < size)
        return wf_error(WF_ERR_CORRUPT, "%s: %lld trailing bytes after section %d: damaged or truncated", path,
                        (long long)(size - end), nhdu);
    if (expect > 0 && nhdu != expect)
        return wf_error(WF_ERR_CORRUPT, "%s: %d sections, expected %d%s", path, nhdu, expect,
                        nhdu < expect ? ": truncated" : "");
    for (int h = 1; h <= nhdu; h++) {
        int dataok = 0, hduok = 0;
        char doing[64];
        snprintf(doing, sizeof doing, "verifying the checksums of section %d", h);
        if (fits_movabs_hdu(f, h, NULL, &status) || fits_verify_chksum(f, &dataok, &hduok, &status))
            return wf_fits_error(status, path, doing);
        /* 0 means the keyword is absent: a file this project wrote always has both */
        if (hduok == 0 || dataok == 0)
            return wf_error(WF_ERR_CORRUPT, "%s: section %d has no %s", path, h, hduok == 0 ? "CHECKSUM" : "DATASUM");
        if (dataok != 1)
            return wf_error(WF_ERR_CORRUPT, "%s: section %d: DATASUM does not verify (data damaged)", path, h);
        if (hduok != 1)
            return wf_error(WF_ERR_CORRUPT, "%s: section %d: CHECKSUM does not verify (header damaged)", path, h);
    }
    return WF_OK;
}

wf_status wf_fits_verify_checksums(const char *path, int nhdu)
{
    fitsfile *f;
    int status = 0;
    if (fits_open_diskfile(&f, path, READONLY, &status)) return wf_fits_error(status, path, "opening");
    wf_status st = verify_open(f, path, nhdu);
    fits_close_file(f, &status);
    fits_clear_errmsg();
    return st;
}

int wf_fits_double_digits(double v)
{
    char buf[40];
    for (int d = 1; d < 17; d++) {
        snprintf(buf, sizeof buf, "%.*G", d, v);
        if (strtod(buf, NULL) == v) return d;
    }
    return 17;
}

wf_status wf_fits_begin(const char *path, char *tmp, size_t tmp_size, fitsfile **f)
{
    if ((size_t)snprintf(tmp, tmp_size, "%s.tmp", path) >= tmp_size)
        return wf_error(WF_ERR_INPUT, "%s: path too long", path);
    unlink(tmp);
    int status = 0;
    wf_fitsdisk_create(f, tmp, &status); /* the name as given: no cfitsio filename syntax */
    return wf_fits_error(status, tmp, "creating the file");
}

wf_status wf_fits_finish(fitsfile *f, const char *tmp, const char *path, wf_status st)
{
    int status = 0;
    if (!st) st = wf_fits_checksum_all(f, tmp, NULL, 0);
    fits_close_file(f, &status);
    if (!st) st = wf_fits_error(status, tmp, "closing");
    if (!st) st = wf_file_rename(tmp, path);
    if (st) unlink(tmp);
    return st;
}
