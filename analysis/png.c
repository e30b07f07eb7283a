#include "analysis/png.h"
#include "hal/file.h"

#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

/* Small IDAT chunks cost 12 bytes each; readers stream them either way. */
#define IDAT_MAX 65536u

static void put32(unsigned char *b, uint32_t v)
{
    b[0] = (unsigned char)(v >> 24);
    b[1] = (unsigned char)(v >> 16);
    b[2] = (unsigned char)(v >> 8);
    b[3] = (unsigned char)v;
}

static int write_chunk(FILE *fp, const char *type, const unsigned char *data, uint32_t len)
{
    unsigned char head[8], tail[4];
    put32(head, len);
    memcpy(head + 4, type, 4);
    uLong crc = crc32(0L, (const Bytef *)type, 4);
    /* crc32(c, NULL, 0) would restart the CRC rather than leave it alone */
    if (len) crc = crc32(crc, data, len);
    put32(tail, (uint32_t)crc);
    return fwrite(head, 1, 8, fp) == 8 && (!len || fwrite(data, 1, len, fp) == len) &&
           fwrite(tail, 1, 4, fp) == 4;
}

static unsigned paeth(unsigned a, unsigned b, unsigned c)
{
    int p = (int)a + (int)b - (int)c, pa = abs(p - (int)a), pb = abs(p - (int)b),
        pc = abs(p - (int)c);
    return pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
}

/* One row filtered with filter f (0..4) into out; returns the sum of |residual| as signed bytes. */
static unsigned long filter_row(int f, const unsigned char *row, const unsigned char *up,
                                size_t stride, unsigned char *out)
{
    unsigned long cost = 0;
    for (size_t i = 0; i < stride; i++) {
        unsigned a = i >= 3 ? row[i - 3] : 0, b = up ? up[i] : 0,
                 c = up && i >= 3 ? up[i - 3] : 0;
        unsigned pred = f == 1 ? a : f == 2 ? b : f == 3 ? (a + b) / 2 : f == 4 ? paeth(a, b, c) : 0;
        unsigned char v = (unsigned char)(row[i] - pred);
        out[i] = v;
        cost += v < 128 ? v : 256u - v;
    }
    return cost;
}

/* The filtered scanlines (filter byte + row each), deflated into *z (malloc'd). */
static wf_status deflate_image(const char *path, const unsigned char *rgb, int w, int h,
                               unsigned char **z, uLong *zlen)
{
    size_t stride = (size_t)w * 3, rawlen = (size_t)h * (stride + 1);
    unsigned char *raw = malloc(rawlen), *cand = malloc(stride * 2);
    if (!raw || !cand) {
        free(raw);
        free(cand);
        return wf_error(WF_ERR_NOMEM, "%s: no memory for a %dx%d image", path, w, h);
    }
    for (int y = 0; y < h; y++) {
        const unsigned char *row = rgb + (size_t)y * stride, *up = y ? row - stride : NULL;
        unsigned char *dst = raw + (size_t)y * (stride + 1);
        unsigned long best = filter_row(0, row, up, stride, dst + 1);
        dst[0] = 0;
        for (int f = 1; f <= 4; f++) {
            unsigned long cost = filter_row(f, row, up, stride, cand);
            if (cost < best) {
                best = cost;
                dst[0] = (unsigned char)f;
                memcpy(dst + 1, cand, stride);
            }
        }
    }
    free(cand);
    *zlen = compressBound((uLong)rawlen);
    *z = malloc(*zlen);
    int zst = *z ? compress2(*z, zlen, raw, (uLong)rawlen, Z_DEFAULT_COMPRESSION) : Z_MEM_ERROR;
    free(raw);
    if (zst != Z_OK) {
        free(*z);
        *z = NULL;
        return wf_error(WF_ERR_NOMEM, "%s: deflate failed (zlib %d)", path, zst);
    }
    return WF_OK;
}

wf_status wf_png_write_rgb(const char *path, const unsigned char *rgb, int width, int height)
{
    if (!path || !*path) return wf_error(WF_ERR_INPUT, "PNG: no output path");
    if (!rgb || width < 1 || height < 1 || (double)width * height * 3 > (double)(1u << 30))
        return wf_error(WF_ERR_RANGE, "%s: image size %dx%d outside 1..2^30/3 pixels", path,
                        width, height);
    unsigned char *z;
    uLong zlen;
    wf_status st = deflate_image(path, rgb, width, height, &z, &zlen);
    if (st) return st;

    size_t n = strlen(path) + 5;
    char *tmp = malloc(n);
    if (!tmp) {
        free(z);
        return wf_error(WF_ERR_NOMEM, "%s: no memory", path);
    }
    snprintf(tmp, n, "%s.tmp", path);
    FILE *fp = fopen(tmp, "wb");
    if (!fp) {
        st = wf_error(WF_ERR_IO, "%s: cannot create %s: %s", path, tmp, strerror(errno));
        goto out;
    }
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    unsigned char ihdr[13];
    put32(ihdr, (uint32_t)width);
    put32(ihdr + 4, (uint32_t)height);
    ihdr[8] = 8;  /* bits per sample */
    ihdr[9] = 2;  /* truecolour */
    ihdr[10] = ihdr[11] = ihdr[12] = 0; /* deflate, adaptive filtering, no interlace */
    int ok = fwrite(sig, 1, 8, fp) == 8 && write_chunk(fp, "IHDR", ihdr, 13);
    for (uLong off = 0; ok && off < zlen; off += IDAT_MAX)
        ok = write_chunk(fp, "IDAT", z + off, (uint32_t)(zlen - off < IDAT_MAX ? zlen - off : IDAT_MAX));
    ok = ok && write_chunk(fp, "IEND", NULL, 0);
    int err = ok ? 0 : errno;
    if (fclose(fp) != 0 && ok) {
        ok = 0;
        err = errno;
    }
    if (!ok)
        st = wf_error(WF_ERR_IO, "%s: cannot write %s: %s", path, tmp, strerror(err));
    else
        st = wf_file_rename(tmp, path);
    if (st) remove(tmp);
out:
    free(tmp);
    free(z);
    return st;
}
