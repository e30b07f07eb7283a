#include "hal/packet.h"

#include "hal/arena.h"
#include "hal/size.h"

#include <inttypes.h>
#include <libdeflate.h>

#include <stdlib.h>
#include <string.h>

/* The packets' CRC-32 (the zlib/gzip polynomial, so zlib's crc32 gives the same values) by
 * libdeflate, whose carry-less-multiply folding runs ~2.3x faster than zlib's here: every
 * byte of the stream is checked on both sides of the link. */
static uint32_t crc(const void *p, size_t n) { return (uint32_t)libdeflate_crc32(0, p, n); }

static void put16(unsigned char *p, uint16_t v) { p[0] = (unsigned char)v; p[1] = (unsigned char)(v >> 8); }
static void put32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (unsigned char)(v >> (8 * i));
}
static uint16_t get16(const unsigned char *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

void wf_packet_header_write(const wf_packet_header *h, unsigned char o[WF_PACKET_HEADER_SIZE])
{
    put32(o + 0, WF_PACKET_MAGIC);
    put16(o + 4, h->version);
    put16(o + 6, h->kind);
    put32(o + 8, h->exposure);
    put16(o + 12, h->sca);
    put16(o + 14, h->flags);
    put32(o + 16, h->first_row);
    put32(o + 20, h->row_count);
    put32(o + 24, h->ncols);
    put32(o + 28, h->nplanes);
    put32(o + 32, h->payload_len);
    put32(o + 36, h->raw_len);
    put32(o + 40, h->payload_crc);
    put32(o + 44, crc(o, 44));
}

wf_status wf_packet_header_read(const unsigned char in[WF_PACKET_HEADER_SIZE], wf_packet_header *h)
{
    if (get32(in) != WF_PACKET_MAGIC)
        return wf_error(WF_ERR_CORRUPT, "bad magic 0x%08x (not a wfisim packet)", get32(in));
    if (get32(in + 44) != crc(in, 44))
        return wf_error(WF_ERR_CORRUPT, "header CRC mismatch");
    h->version = get16(in + 4);
    h->kind = get16(in + 6);
    h->exposure = get32(in + 8);
    h->sca = get16(in + 12);
    h->flags = get16(in + 14);
    h->first_row = get32(in + 16);
    h->row_count = get32(in + 20);
    h->ncols = get32(in + 24);
    h->nplanes = get32(in + 28);
    h->payload_len = get32(in + 32);
    h->raw_len = get32(in + 36);
    h->payload_crc = get32(in + 40);
    if (h->version != WF_PACKET_VERSION)
        return wf_error(WF_ERR_CORRUPT, "packet version %u, this build reads %d", h->version,
                        WF_PACKET_VERSION);
    if (h->kind < WF_PK_META || h->kind > WF_PK_LAST)
        return wf_error(WF_ERR_CORRUPT, "unknown packet kind %u", h->kind);
    return WF_OK;
}

/* zlib asks for memory through these: deflate state lives in the arena, allocated once at
 * wf_packer_init (deflateReset reuses it), so nothing is freed until the arena is dropped. */
static voidpf arena_zalloc(voidpf opaque, uInt items, uInt size)
{
    void *p = NULL;
    if (wf_arena_calloc(opaque, items, size, "deflate state", &p) != WF_OK)
        return Z_NULL;
    return p;
}
static void arena_zfree(voidpf opaque, voidpf p) { (void)opaque; (void)p; }

/* deflateInit2(level 1, windowBits 15, memLevel 8) reserves about 268 KiB plus our margin.
 * Huffman coding only (no string matching): noisy pixel data has few repeats to match, and
 * it costs 0.3 instead of 0.55 CPU-s on a full single-frame SCA for a 30% larger stream;
 * any zlib inflater reads it unchanged. */
#define DEFLATE_STATE_BYTES (300u * 1024u)

size_t wf_packer_arena_need(size_t max_raw, int compress)
{
    size_t wire = wf_size_add(max_raw, max_raw / 1000 + 64); /* covers deflateBound for stored blocks */
    return wf_size_add(wf_arena_cost(wf_size_add(WF_PACKET_HEADER_SIZE, wire)),
                       compress ? DEFLATE_STATE_BYTES : 0);
}

wf_status wf_packer_init(wf_packer *pk, wf_arena *arena, size_t max_raw, int compress)
{
    memset(pk, 0, sizeof *pk);
    pk->compress = compress;
    size_t wire = max_raw + max_raw / 1000 + 64;
    if (compress) {
        pk->z.zalloc = arena_zalloc;
        pk->z.zfree = arena_zfree;
        pk->z.opaque = arena;
        if (deflateInit2(&pk->z, 1, Z_DEFLATED, 15, 8, Z_HUFFMAN_ONLY) != Z_OK)
            return wf_error(WF_ERR_NOMEM, "packer: deflate state does not fit the arena");
        pk->z_ready = 1;
        size_t bound = deflateBound(&pk->z, (uLong)max_raw);
        if (bound > wire) wire = bound;
    }
    pk->cap = WF_PACKET_HEADER_SIZE + wire;
    void *buf;
    wf_status st = wf_arena_alloc(arena, pk->cap, "packet buffer", &buf);
    pk->buf = buf;
    return st;
}

void wf_packer_close(wf_packer *pk)
{
    if (pk->z_ready)
        deflateEnd(&pk->z);
    pk->z_ready = 0;
}

void *wf_packer_scratch(wf_packer *pk, size_t *bytes)
{
    *bytes = pk->cap;
    return pk->buf;
}

wf_status wf_packer_send(wf_packer *pk, const wf_link *link, wf_packet_header *h,
                         const void *raw, size_t raw_len)
{
    unsigned char *payload = pk->buf + WF_PACKET_HEADER_SIZE;
    size_t room = pk->cap - WF_PACKET_HEADER_SIZE;
    size_t wire_len = raw_len;
    h->version = WF_PACKET_VERSION;
    h->flags = 0;
    if (raw_len > UINT32_MAX)
        return wf_error(WF_ERR_INTERNAL, "packet payload of %zu bytes too large", raw_len);
    if (pk->compress && raw_len > 0) {
        deflateReset(&pk->z);
        pk->z.next_in = (Bytef *)(uintptr_t)raw;
        pk->z.avail_in = (uInt)raw_len;
        pk->z.next_out = payload;
        pk->z.avail_out = (uInt)room;
        if (deflate(&pk->z, Z_FINISH) != Z_STREAM_END)
            return wf_error(WF_ERR_INTERNAL, "deflate did not finish in %zu bytes", room);
        wire_len = room - pk->z.avail_out;
        h->flags |= WF_PACKET_FLAG_DEFLATE;
    } else {
        if (raw_len > room)
            return wf_error(WF_ERR_INTERNAL, "packet payload of %zu bytes exceeds buffer of %zu",
                            raw_len, room);
        if (raw_len) memcpy(payload, raw, raw_len);
    }
    h->payload_len = (uint32_t)wire_len;
    h->raw_len = (uint32_t)raw_len;
    h->payload_crc = crc(payload, wire_len);
    wf_packet_header_write(h, pk->buf);
    return wf_link_send(link, pk->buf, WF_PACKET_HEADER_SIZE + wire_len);
}

void wf_packet_rows_text(const wf_packet_header *h, char *buf, size_t n)
{
    if (n) buf[0] = '\0';
    /* META and END carry no rows (END's row_count is the exposure's height); 64 bits, so
     * that a damaged header's numbers are printed as they are, not wrapped */
    if (h->row_count == 0 || h->kind == WF_PK_END) return;
    snprintf(buf, n, "rows %" PRIu32 "-%" PRIu64, h->first_row, (uint64_t)h->first_row + h->row_count - 1);
}

long wf_packet_read_file(void *ctx, void *buf, size_t n)
{
    FILE *f = ctx;
    size_t got = fread(buf, 1, n, f);
    return got < n && ferror(f) ? -1 : (long)got;
}

void wf_packet_reader_open_source(wf_packet_reader *r, wf_packet_read_fn read, void *ctx,
                                  const char *name)
{
    memset(r, 0, sizeof *r);
    r->read = read;
    r->ctx = ctx;
    r->name = name;
}

void wf_packet_reader_open(wf_packet_reader *r, FILE *file, const char *name)
{
    wf_packet_reader_open_source(r, wf_packet_read_file, file, name);
}

void wf_packet_reader_close(wf_packet_reader *r)
{
    free(r->wire);
    free(r->raw);
    r->wire = r->raw = NULL;
}

static wf_status grow(unsigned char **buf, size_t *cap, size_t need)
{
    if (need <= *cap) return WF_OK;
    /* a power of two, so that a full tile's packet (just under 1 MiB) takes a huge page; past
     * 64 MiB (rare, huge tiles) just the need */
    size_t c = 4096;
    while (c < need && c < ((size_t)64 << 20)) c *= 2;
    if (c < need) c = need;
    unsigned char *p = wf_arena_host_realloc(*buf, 0, c); /* a packet overwrites it whole */
    if (!p) return wf_error(WF_ERR_NOMEM, "cannot allocate %zu bytes for a packet", need);
    *buf = p;
    *cap = c;
    return WF_OK;
}

wf_status wf_packet_reader_next(wf_packet_reader *r, wf_packet_header *h, const void **payload,
                                int *eof)
{
    unsigned char hb[WF_PACKET_HEADER_SIZE];
    *eof = 0;
    *payload = NULL;
    long got = r->read(r->ctx, hb, sizeof hb);
    if (got < 0)
        return wf_error(WF_ERR_IO, "%s: read error at offset %llu", r->name, (unsigned long long)r->offset);
    if (got == 0) {
        *eof = 1;
        return WF_OK;
    }
    if (got != (long)sizeof hb)
        return wf_error(WF_ERR_CORRUPT, "%s: truncated stream: %ld of %d header bytes at offset %llu",
                        r->name, got, WF_PACKET_HEADER_SIZE, (unsigned long long)r->offset);
    wf_status st = wf_packet_header_read(hb, h);
    if (st != WF_OK) {
        char why[256];
        snprintf(why, sizeof why, "%s", wf_error_message());
        return wf_error(st, "%s: packet %ld at offset %llu: %s", r->name, r->count + 1,
                        (unsigned long long)r->offset, why);
    }
    /* A header with a valid CRC can still be crafted: bound both lengths before allocating. */
    if (h->payload_len > WF_PACKET_MAX_PAYLOAD || h->raw_len > WF_PACKET_MAX_PAYLOAD)
        return wf_error(WF_ERR_CORRUPT, "%s: packet %ld at offset %llu claims %u/%u payload bytes (limit %u)",
                        r->name, r->count + 1, (unsigned long long)r->offset, h->payload_len,
                        h->raw_len, (unsigned)WF_PACKET_MAX_PAYLOAD);
    if ((st = grow(&r->wire, &r->wire_cap, (size_t)h->payload_len + 1u)) != WF_OK) return st;
    got = h->payload_len ? r->read(r->ctx, r->wire, h->payload_len) : 0;
    if (got < 0)
        return wf_error(WF_ERR_IO, "%s: read error in packet %ld at offset %llu", r->name, r->count + 1,
                        (unsigned long long)r->offset);
    char rows[48];
    wf_packet_rows_text(h, rows, sizeof rows);
    if (got != (long)h->payload_len)
        return wf_error(WF_ERR_CORRUPT, "%s: truncated stream: packet %ld (kind %u%s%s) at offset %llu ends early",
                        r->name, r->count + 1, h->kind, rows[0] ? ", " : "", rows, (unsigned long long)r->offset);
    if (crc(r->wire, h->payload_len) != h->payload_crc)
        return wf_error(WF_ERR_CORRUPT, "%s: bad CRC in packet %ld (kind %u%s%s) at offset %llu",
                        r->name, r->count + 1, h->kind, rows[0] ? ", " : "", rows, (unsigned long long)r->offset);
    if (h->flags & WF_PACKET_FLAG_DEFLATE) {
        if ((st = grow(&r->raw, &r->raw_cap, (size_t)h->raw_len + 1u)) != WF_OK) return st;
        uLongf out_len = h->raw_len;
        if (uncompress(r->raw, &out_len, r->wire, h->payload_len) != Z_OK || out_len != h->raw_len)
            return wf_error(WF_ERR_CORRUPT, "%s: packet %ld (kind %u%s%s) does not inflate to %u bytes",
                            r->name, r->count + 1, h->kind, rows[0] ? ", " : "", rows, h->raw_len);
        *payload = r->raw;
    } else {
        if (h->raw_len != h->payload_len)
            return wf_error(WF_ERR_CORRUPT, "%s: packet %ld: raw length %u != payload length %u",
                            r->name, r->count + 1, h->raw_len, h->payload_len);
        *payload = r->wire;
    }
    r->offset += WF_PACKET_HEADER_SIZE + h->payload_len;
    r->count++;
    return WF_OK;
}
