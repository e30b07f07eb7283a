#include "sim/fits/rice.h"

#include <string.h>

/* A bit stream written most significant bit first: the pending bits are the low nb bits of
 * acc (nb < 32 between calls), flushed 32 at a time. The flush is branch-free: 4 bytes are
 * stored after every put and kept only when 32 bits were ready (the bit count's branch was
 * mispredicted about once a pixel); so the output needs 4 bytes of room beyond its last word,
 * which wf_fits_rice_bound's 16 bytes of slack give. */
typedef struct bits {
    uint64_t acc;
    int nb;
    unsigned char *p;
} bits;

static inline void put(bits *b, uint64_t v, int n) /* n <= 32, v < 2^n */
{
    b->acc = (b->acc << n) | v;
    b->nb += n;
    const int full = b->nb >= 32;
    uint32_t w = (uint32_t)(b->acc >> (b->nb & 31));
#if !defined(__BYTE_ORDER__) || __BYTE_ORDER__ != __ORDER_BIG_ENDIAN__
    w = __builtin_bswap32(w);
#endif
    memcpy(b->p, &w, 4);
    b->nb -= 32 * full;
    b->p += 4 * full;
}

/* The last bits, the final byte padded with zeros. */
static void flush(bits *b)
{
    while (b->nb >= 8) {
        b->nb -= 8;
        *b->p++ = (unsigned char)(b->acc >> b->nb);
    }
    if (b->nb > 0) *b->p++ = (unsigned char)(b->acc << (8 - b->nb));
    b->nb = 0;
}

size_t wf_fits_rice_bound(long n, int bytepix)
{
    /* the split keeps a block's unary parts below 2.5 bits a pixel plus 1, so a pixel costs
     * at most max(8 bytepix, fsmax + 2.5) bits and a block fsbits + 1 more: within
     * bytepix + 2 bytes a pixel for any block size, with the first pixel and the last byte */
    return (size_t)(n > 0 ? n : 0) * (size_t)(bytepix + 2) + (size_t)bytepix + 16;
}

/* Differences of neighbours mapped to unsigned values (0, -1, 1, -2 .. -> 0, 1, 2, 3 ..),
 * in the pixels' own width: the first pixel's is against itself (0). */
static void map16(const uint16_t *a, long n, uint32_t *d)
{
    d[0] = 0;
    for (long i = 1; i < n; i++) {
        int32_t x = (int16_t)(uint16_t)(a[i] - a[i - 1]);
        d[i] = (uint32_t)((x * 2) ^ (x >> 31)); /* 0 .. 65535 */
    }
}

static void map32(const uint32_t *a, long n, uint32_t *d)
{
    d[0] = 0;
    for (long i = 1; i < n; i++) {
        uint32_t u = a[i] - a[i - 1];
        d[i] = (u << 1) ^ (uint32_t)-(int32_t)(u >> 31);
    }
}

wf_status wf_fits_rice_code(const void *pix, long n, int bytepix, uint32_t flip, int block,
                            unsigned char *out, size_t cap, size_t *len)
{
    *len = 0;
    enum { CHUNK = 4096 }; /* pixels mapped at once: whole blocks */
    if (n < 1 || (bytepix != 2 && bytepix != 4) || block < 1 || block > CHUNK || cap < wf_fits_rice_bound(n, bytepix))
        return wf_error(WF_ERR_INTERNAL, "Rice code: %ld pixels of %d bytes, block %d, %zu bytes of room", n,
                        bytepix, block, cap);
    const int fsbits = bytepix == 2 ? 4 : 5, fsmax = bytepix == 2 ? 14 : 25, bbits = 8 * bytepix;
    uint32_t d[CHUNK + 1];
    bits b = {0, 0, out};
    uint32_t first = bytepix == 2 ? (uint32_t)(((const uint16_t *)pix)[0] ^ flip) & 0xffffu
                                  : ((const uint32_t *)pix)[0] ^ flip;
    put(&b, first, bbits);
    /* the differences a chunk of whole blocks at a time (the neighbour before a chunk is the
     * previous chunk's last pixel) */
    const long per = (CHUNK / block) * (long)block;
    for (long c0 = 0; c0 < n; c0 += per) {
        long m = n - c0 < per ? n - c0 : per;
        uint32_t *dd = d;
        long from = c0 > 0 ? c0 - 1 : 0, cnt = c0 > 0 ? m + 1 : m;
        if (bytepix == 2) map16((const uint16_t *)pix + from, cnt, dd);
        else map32((const uint32_t *)pix + from, cnt, dd);
        if (c0 > 0) dd++; /* drop the neighbour's own entry */
        for (long i = 0; i < m; i += block) {
            const int nb = m - i < block ? (int)(m - i) : block;
            const uint32_t *v = dd + i;
            uint64_t sum = 0;
            for (int j = 0; j < nb; j++) sum += v[j];
            /* cfitsio's split: the bit length of (mean - 1/2, rounded down) / 2 */
            const uint64_t h = (uint64_t)(nb / 2) + 1;
            const uint64_t q = sum >= h ? (sum - h) / (uint64_t)nb : 0;
            const uint64_t ps = q >> 1;
            const int fs = ps ? 64 - __builtin_clzll(ps) : 0;
            if (fs >= fsmax) { /* high entropy: the differences as they are */
                put(&b, (uint64_t)fsmax + 1, fsbits);
                for (int j = 0; j < nb; j++) put(&b, v[j], bbits);
            } else if (sum == 0) { /* every difference zero */
                put(&b, 0, fsbits);
            } else {
                put(&b, (uint64_t)fs + 1, fsbits);
                const uint32_t mask = (1u << fs) - 1u;
                int j = 0;
                /* two codes at once while both are short (nearly always): one put, half the
                 * serial chain through the bit buffer */
                for (; j + 1 < nb; j += 2) {
                    const uint32_t t0 = v[j] >> fs, t1 = v[j + 1] >> fs;
                    const uint32_t n0 = t0 + 1 + (uint32_t)fs, n1 = t1 + 1 + (uint32_t)fs;
                    if (n0 + n1 > 32) break;
                    const uint64_t k0 = (1ull << fs) | (v[j] & mask), k1 = (1ull << fs) | (v[j + 1] & mask);
                    put(&b, (k0 << n1) | k1, (int)(n0 + n1));
                }
                for (; j < nb; j++) {
                    uint32_t top = v[j] >> fs;
                    if (top + 1 + (uint32_t)fs <= 32) {
                        put(&b, (1ull << fs) | (v[j] & mask), (int)top + 1 + fs);
                    } else { /* a long unary run */
                        for (; top >= 32; top -= 32) put(&b, 0, 32);
                        put(&b, 1, (int)top + 1);
                        if (fs) put(&b, v[j] & mask, fs);
                    }
                }
            }
        }
    }
    flush(&b);
    *len = (size_t)(b.p - out);
    return WF_OK;
}
