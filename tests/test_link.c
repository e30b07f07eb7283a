/* The in-process pipe (hal/link.h): bytes arrive whole and in order through a ring smaller
 * than the packets; packets of several sending threads never interleave; the end of the
 * stream is a short read; a reader that stops makes senders fail at once instead of hang;
 * and the packet reader decodes a stream through it as through a FILE. */
#include <pthread.h>
#include <stdio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "hal/link.h"
#include "hal/packet.h"
#include "tests/testutil.h"

/* Packet p of sender s: a length and a byte pattern both derived from (s, p). */
static size_t packet_len(int s, int p) { return 16 + (size_t)((s * 7919 + p * 104729) % 20000); }
static unsigned char packet_byte(int s, int p, size_t i) { return (unsigned char)(s * 31 + p * 17 + i * 13); }

typedef struct sender {
    wf_link link;
    int index, npackets;
    wf_status status;
    char message[256]; /* the error message, on the sender's thread */
} sender;

static void *send_main(void *arg)
{
    sender *sd = arg;
    unsigned char *buf = malloc(64 * 1024);
    for (int p = 0; p < sd->npackets && buf; p++) {
        size_t n = packet_len(sd->index, p);
        /* header: sender, packet, length; then the pattern */
        uint32_t hdr[3] = {(uint32_t)sd->index, (uint32_t)p, (uint32_t)n};
        memcpy(buf, hdr, sizeof hdr);
        for (size_t i = sizeof hdr; i < n; i++) buf[i] = packet_byte(sd->index, p, i);
        if ((sd->status = wf_link_send(&sd->link, buf, n))) break;
    }
    free(buf);
    return NULL;
}

START_TEST(pipe_packets_whole_and_in_order)
{
    /* a 4 KiB ring (the smallest) and packets up to 20 KiB from three threads */
    enum { SENDERS = 3, PACKETS = 400 };
    wf_link_pipe lp;
    wf_link link;
    ck_assert_int_eq(wf_link_pipe_open(&lp, 4096, "test pipe", &link), WF_OK);
    sender sd[SENDERS];
    pthread_t th[SENDERS];
    for (int s = 0; s < SENDERS; s++) {
        sd[s] = (sender){link, s, PACKETS, WF_OK, ""};
        ck_assert_int_eq(pthread_create(&th[s], NULL, send_main, &sd[s]), 0);
    }
    int next[SENDERS] = {0};
    unsigned char *buf = malloc(64 * 1024);
    long total = 0;
    for (int k = 0; k < SENDERS * PACKETS; k++) {
        uint32_t hdr[3];
        ck_assert_uint_eq(wf_link_pipe_read(&lp, hdr, sizeof hdr), sizeof hdr);
        ck_assert_uint_lt(hdr[0], SENDERS);
        int s = (int)hdr[0], p = (int)hdr[1];
        ck_assert_msg(p == next[s], "sender %d: packet %d after %d", s, p, next[s] - 1);
        ck_assert_uint_eq(hdr[2], packet_len(s, p));
        size_t body = hdr[2] - sizeof hdr;
        ck_assert_uint_eq(wf_link_pipe_read(&lp, buf, body), body);
        for (size_t i = 0; i < body; i++)
            if (buf[i] != packet_byte(s, p, i + sizeof hdr))
                ck_abort_msg("sender %d packet %d: byte %zu differs (interleaved?)", s, p, i);
        next[s]++;
        total += (long)hdr[2];
    }
    for (int s = 0; s < SENDERS; s++) {
        pthread_join(th[s], NULL);
        ck_assert_int_eq(sd[s].status, WF_OK);
    }
    /* the end: a short read once the writer closes */
    wf_link_pipe_close_write(&lp);
    ck_assert_uint_eq(wf_link_pipe_read(&lp, buf, 10), 0);
    ck_assert(!lp.refused);
    wf_link_pipe_free(&lp);
    free(buf);
    printf("pipe: %d packets, %ld bytes through a 4 KiB ring, none interleaved\n", SENDERS * PACKETS, total);
}
END_TEST

START_TEST(pipe_end_of_stream_mid_read)
{
    wf_link_pipe lp;
    wf_link link;
    ck_assert_int_eq(wf_link_pipe_open(&lp, 8192, "test pipe", &link), WF_OK);
    const char msg[] = "seven bytes";
    ck_assert_int_eq(wf_link_send(&link, msg, 7), WF_OK);
    wf_link_pipe_close_write(&lp);
    char got[32];
    ck_assert_uint_eq(wf_link_pipe_read(&lp, got, sizeof got), 7);
    ck_assert(!memcmp(got, msg, 7));
    ck_assert_uint_eq(wf_link_pipe_read(&lp, got, sizeof got), 0);
    wf_link_pipe_free(&lp);
}
END_TEST

static void *send_forever(void *arg)
{
    sender *sd = arg;
    static unsigned char block[100000];
    while (!(sd->status = wf_link_send(&sd->link, block, sizeof block))) sd->npackets++;
    snprintf(sd->message, sizeof sd->message, "%s", wf_error_message());
    return NULL;
}

START_TEST(pipe_reader_stops)
{
    /* a sender blocked on a full ring gets an error once the reader closes, not a hang
     * (the test's timeout would catch one) */
    wf_link_pipe lp;
    wf_link link;
    ck_assert_int_eq(wf_link_pipe_open(&lp, 4096, "test pipe", &link), WF_OK);
    sender sd = {link, 0, 0, WF_OK, ""};
    pthread_t th;
    ck_assert_int_eq(pthread_create(&th, NULL, send_forever, &sd), 0);
    unsigned char buf[1000];
    ck_assert_uint_eq(wf_link_pipe_read(&lp, buf, sizeof buf), sizeof buf);
    wf_link_pipe_close_read(&lp);
    pthread_join(th, NULL);
    ck_assert_int_eq(sd.status, WF_ERR_IO);
    ck_assert_msg(strstr(sd.message, "test pipe") && strstr(sd.message, "reader has stopped"), "%s", sd.message);
    ck_assert(lp.refused);
    ck_assert_int_eq(sd.npackets, 0);
    wf_link_pipe_free(&lp);
}
END_TEST

typedef struct packer_job {
    wf_link link;
    wf_status status;
    int npackets;
} packer_job;

static void *pack_main(void *arg)
{
    packer_job *pj = arg;
    static float rows[16 * 4096];
    size_t need = wf_packer_arena_need(sizeof rows, 1);
    void *mem = malloc(need);
    ck_assert_ptr_nonnull(mem);
    wf_arena arena;
    wf_arena_init(&arena, mem, need, "test packer");
    wf_packer pk;
    pj->status = wf_packer_init(&pk, &arena, sizeof rows, 1);
    for (int p = 0; p < pj->npackets && !pj->status; p++) {
        for (int i = 0; i < 16 * 4096; i++) rows[i] = (float)(p * 1000 + i % 977);
        wf_packet_header h = {0};
        h.kind = WF_PK_SINGLE;
        h.first_row = (uint32_t)(16 * p);
        h.row_count = 16;
        h.ncols = 4096;
        h.nplanes = 1;
        pj->status = wf_packer_send(&pk, &pj->link, &h, rows, sizeof rows);
    }
    wf_packer_close(&pk);
    free(mem);
    return NULL;
}

static long read_pipe(void *ctx, void *buf, size_t n) { return (long)wf_link_pipe_read(ctx, buf, n); }

START_TEST(packet_reader_through_pipe)
{
    /* packets of 256 KiB, deflated, through a 64 KiB ring, decoded by the packet reader */
    wf_link_pipe lp;
    wf_link link;
    ck_assert_int_eq(wf_link_pipe_open(&lp, 65536, "test pipe", &link), WF_OK);
    packer_job pj = {link, WF_OK, 12};
    pthread_t th;
    ck_assert_int_eq(pthread_create(&th, NULL, pack_main, &pj), 0);
    wf_packet_reader r;
    wf_packet_reader_open_source(&r, read_pipe, &lp, "test pipe");
    int n = 0;
    for (;;) {
        wf_packet_header h;
        const void *payload;
        int eof;
        if (n == pj.npackets) {
            pthread_join(th, NULL);
            ck_assert_int_eq(pj.status, WF_OK);
            wf_link_pipe_close_write(&lp);
        }
        ck_assert_msg(wf_packet_reader_next(&r, &h, &payload, &eof) == WF_OK, "%s", wf_error_message());
        if (eof) break;
        ck_assert_uint_eq(h.first_row, 16u * (unsigned)n);
        const float *f = payload;
        for (int i = 0; i < 16 * 4096; i += 4097) ck_assert(f[i] == (float)(n * 1000 + i % 977));
        n++;
    }
    ck_assert_int_eq(n, pj.npackets);
    wf_packet_reader_close(&r);
    wf_link_pipe_free(&lp);
}
END_TEST

/* The packets' CRCs (hal/packet.c, libdeflate) are zlib's CRC-32, the stream format's own:
 * both the header's and the payload's, raw and deflated, of lengths that are not multiples
 * of the folding's 16- or 64-byte blocks. */
START_TEST(packet_crcs_are_zlib_crc32)
{
    for (int compress = 0; compress < 2; compress++)
        for (size_t raw = 1; raw < 5000; raw = raw * 3 + 1) {
            unsigned char *data = malloc(raw);
            ck_assert_ptr_nonnull(data);
            for (size_t i = 0; i < raw; i++) data[i] = (unsigned char)(i * 2654435761u >> 11);
            size_t need = wf_packer_arena_need(raw, compress) + 64; /* malloc's base may be unaligned */
            void *mem = malloc(need);
            wf_arena arena;
            wf_arena_init(&arena, mem, need, "test packer");
            wf_packer pk;
            ck_assert_msg(wf_packer_init(&pk, &arena, raw, compress) == WF_OK, "raw %zu compress %d: %s", raw, compress, wf_error_message());
            wf_link_memory m;
            wf_link link;
            ck_assert_int_eq(wf_link_memory_open(&m, &link), WF_OK);
            wf_packet_header h = {0};
            h.kind = WF_PK_SATURATION;
            h.row_count = 1;
            h.ncols = (uint32_t)raw;
            h.nplanes = 1;
            ck_assert_int_eq(wf_packer_send(&pk, &link, &h, data, raw), WF_OK);
            ck_assert_uint_eq(m.len, WF_PACKET_HEADER_SIZE + h.payload_len);
            const unsigned char *o = m.data;
            uint32_t hcrc = (uint32_t)o[44] | (uint32_t)o[45] << 8 | (uint32_t)o[46] << 16 | (uint32_t)o[47] << 24;
            ck_assert_uint_eq(hcrc, (uint32_t)crc32(0L, o, 44));
            ck_assert_uint_eq(h.payload_crc, (uint32_t)crc32(0L, o + WF_PACKET_HEADER_SIZE, (uInt)h.payload_len));
            wf_link_memory_close(&m);
            wf_packer_close(&pk);
            free(mem);
            free(data);
        }
}
END_TEST

/* A damaged packet's message gives its rows as they are: none for META and END (a META's
 * row_count of 0 once printed as "rows 0-4294967295"), and a crafted header's numbers
 * without wrapping at 2^32. */
START_TEST(damaged_packet_rows_named)
{
    wf_packet_header h = {0};
    char rows[48];
    h.kind = WF_PK_META;
    wf_packet_rows_text(&h, rows, sizeof rows);
    ck_assert_str_eq(rows, "");
    h.kind = WF_PK_END;
    h.row_count = 4088; /* END's count is the exposure's height */
    wf_packet_rows_text(&h, rows, sizeof rows);
    ck_assert_str_eq(rows, "");
    h.kind = WF_PK_RESULTANTS;
    h.first_row = 64;
    h.row_count = 64;
    wf_packet_rows_text(&h, rows, sizeof rows);
    ck_assert_str_eq(rows, "rows 64-127");
    h.first_row = UINT32_MAX - 1;
    h.row_count = 8;
    wf_packet_rows_text(&h, rows, sizeof rows);
    ck_assert_str_eq(rows, "rows 4294967294-4294967301");

    /* a META packet with one payload byte flipped, read back */
    const char *text = "ncols = 1\nnrows = 1\n";
    size_t raw = strlen(text), need = wf_packer_arena_need(raw, 0) + 64;
    void *mem = malloc(need);
    wf_arena arena;
    wf_arena_init(&arena, mem, need, "test packer");
    wf_packer pk;
    ck_assert_int_eq(wf_packer_init(&pk, &arena, raw, 0), WF_OK);
    wf_link_memory m;
    wf_link link;
    ck_assert_int_eq(wf_link_memory_open(&m, &link), WF_OK);
    wf_packet_header meta = {0};
    meta.kind = WF_PK_META;
    ck_assert_int_eq(wf_packer_send(&pk, &link, &meta, text, raw), WF_OK);
    m.data[WF_PACKET_HEADER_SIZE + 3] ^= 0x40;
    FILE *f = fmemopen(m.data, m.len, "rb");
    wf_packet_reader r;
    wf_packet_reader_open(&r, f, "damaged.bin");
    const void *payload;
    int eof;
    ck_assert_int_eq(wf_packet_reader_next(&r, &h, &payload, &eof), WF_ERR_CORRUPT);
    const char *msg = wf_error_message();
    ck_assert_msg(strstr(msg, "bad CRC") && strstr(msg, "kind 1") && !strstr(msg, "rows"), "%s", msg);
    wf_packet_reader_close(&r);
    fclose(f);
    wf_link_memory_close(&m);
    wf_packer_close(&pk);
    free(mem);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("link");
    TCase *tc = tcase_create("link");
    tcase_set_timeout(tc, 60);
    tcase_add_test(tc, pipe_packets_whole_and_in_order);
    tcase_add_test(tc, pipe_end_of_stream_mid_read);
    tcase_add_test(tc, pipe_reader_stops);
    tcase_add_test(tc, packet_reader_through_pipe);
    tcase_add_test(tc, packet_crcs_are_zlib_crc32);
    tcase_add_test(tc, damaged_packet_rows_named);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
