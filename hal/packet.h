/* Packet format of the output link (docs/PACKETS.md is the full description).
 * A packet is a 48-byte little-endian header and a payload; the payload may be
 * deflate-compressed and always carries a CRC-32 (zlib) of its wire bytes, the header a
 * CRC-32 of its first 44 bytes. Firmware encodes through a wf_packer whose buffers and zlib
 * state come from the arena; host tools decode with wf_packet_reader. */
#ifndef WF_PACKET_H
#define WF_PACKET_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <zlib.h>
#include "hal/arena.h"
#include "hal/link.h"

#define WF_PACKET_MAGIC 0x50494657u /* "WFIP" */
#define WF_PACKET_VERSION 1
#define WF_PACKET_HEADER_SIZE 48
#define WF_PACKET_FLAG_DEFLATE 0x1
/* SATURATION value of an unsaturated pixel into which persistence released charge */
#define WF_SAT_PERSISTENCE 254
#define WF_PACKET_MAX_PAYLOAD (1u << 30) /* bytes, wire or raw: a 4088-wide tile of 64 resultants x 1024 rows fits */

typedef enum {
    WF_PK_META = 1,       /* text "key = value" lines: exposure keywords and MA table */
    WF_PK_RESULTANTS = 2, /* uint16 [nplanes][row_count][ncols], ADU */
    WF_PK_SINGLE = 3,     /* float32 [row_count][ncols], ADU (single-frame mode) */
    WF_PK_SATURATION = 4, /* uint8 [row_count][ncols]: first resultant with a saturated read, 255 none,
                           * WF_SAT_PERSISTENCE none but an earlier exposure's charge released here */
    WF_PK_COSMIC = 5,     /* wf_cosmic_record[nplanes]: cosmic-ray truth of hits starting in these rows */
    WF_PK_END = 6,        /* no payload; row_count = rows the exposure has */
    WF_PK_REFCOLS = 7,    /* uint16 [nplanes][row_count][8]: side reference pixels of active rows,
                             full-frame columns 0-3 then the last four; ncols = 8 */
    WF_PK_REFROWS = 8     /* uint16 [nplanes][8][ncols]: reference rows, full-frame rows 0-3
                             then the last four, ncols = the full width; first_row 0, row_count 8 */
} wf_packet_kind;
#define WF_PK_LAST WF_PK_REFROWS

typedef struct wf_packet_header {
    uint16_t version, kind;
    uint32_t exposure;
    uint16_t sca, flags;
    uint32_t first_row, row_count, ncols, nplanes;
    uint32_t payload_len, raw_len;
    uint32_t payload_crc;
} wf_packet_header;

/* Cosmic-ray truth record as it travels (little-endian, packed to 32 bytes). */
typedef struct wf_cosmic_record {
    float x0, y0, x1, y1; /* track ends on the surface, pixel coordinates (0-based centres) */
    float electrons;      /* charge deposited in all */
    uint32_t read;        /* read at which it hit (0-based) */
    uint32_t id;          /* unique within the exposure */
    uint32_t reserved;
} wf_cosmic_record;

typedef struct wf_packer {
    int compress;
    z_stream z;
    int z_ready;
    unsigned char *buf;
    size_t cap;
} wf_packer;

/* Reserves the packet buffer (and deflate state) for payloads up to max_raw bytes. */
wf_status wf_packer_init(wf_packer *pk, wf_arena *arena, size_t max_raw, int compress);
size_t wf_packer_arena_need(size_t max_raw, int compress);
void wf_packer_close(wf_packer *pk);

/* Encodes and sends one packet; h->kind, exposure, sca, first_row, row_count, ncols,
 * nplanes are the caller's, the rest is filled here. */
wf_status wf_packer_send(wf_packer *pk, const wf_link *link, wf_packet_header *h,
                         const void *raw, size_t raw_len);

/* The packet buffer as scratch: free between sends (a send copies or writes the packet
 * before it returns), *bytes long (at least the max_raw of init), 64-byte aligned. */
void *wf_packer_scratch(wf_packer *pk, size_t *bytes);

/* "rows A-B" of a header, for messages; "" for a packet without rows (META, END). */
void wf_packet_rows_text(const wf_packet_header *h, char *buf, size_t n);

/* Header (de)serialisation, exposed for tests and tools. */
void wf_packet_header_write(const wf_packet_header *h, unsigned char out[WF_PACKET_HEADER_SIZE]);
wf_status wf_packet_header_read(const unsigned char in[WF_PACKET_HEADER_SIZE], wf_packet_header *h);

/* Host-side reader (uses malloc: host tools only). It reads through a byte source: a stdio
 * stream, or any function that fills buf with n bytes and returns how many it gave (fewer
 * only at the end of the stream) or -1 on a read error. */
typedef long (*wf_packet_read_fn)(void *ctx, void *buf, size_t n);
typedef struct wf_packet_reader {
    wf_packet_read_fn read;
    void *ctx;
    const char *name;
    unsigned char *wire, *raw;
    size_t wire_cap, raw_cap;
    uint64_t offset; /* byte offset of the next packet, for messages */
    long count;
} wf_packet_reader;

void wf_packet_reader_open(wf_packet_reader *r, FILE *file, const char *name);
void wf_packet_reader_open_source(wf_packet_reader *r, wf_packet_read_fn read, void *ctx,
                                  const char *name);
/* The stdio source wf_packet_reader_open uses (ctx: the FILE). */
long wf_packet_read_file(void *ctx, void *buf, size_t n);
/* Next packet: *eof = 1 at a clean end of stream. The payload (inflated) stays valid until
 * the next call. Any damage is WF_ERR_CORRUPT with the offset and what was wrong. */
wf_status wf_packet_reader_next(wf_packet_reader *r, wf_packet_header *h, const void **payload,
                                int *eof);
void wf_packet_reader_close(wf_packet_reader *r);

#endif
