/* Packet stream (hal/packet.c reader, tools/assemble.c): the input as the stream
 * `wfisim assemble FILE` reads, assembled into FITS in a scratch directory. Every input is
 * fed twice: as it is (bad magic, header and payload CRCs must be caught) and with its
 * CRCs recomputed, so that mutations reach the headers' fields and the payloads behind
 * the checks. After each, no "<name>.tmp" may remain: a damaged stream leaves no half
 * product (tools/assemble.h). */
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <zlib.h>

#include "fuzz/common.h"
#include "hal/packet.h"
#include "tools/assemble.h"

typedef struct source {
    const uint8_t *data;
    size_t size, at;
} source;

static long read_mem(void *ctx, void *buf, size_t n)
{
    source *s = ctx;
    size_t left = s->size - s->at, k = n < left ? n : left;
    memcpy(buf, s->data + s->at, k);
    s->at += k;
    return (long)k;
}

static uint32_t le32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static void put_le32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i));
}

/* Walks the packets as their headers say and rewrites the payload and header CRCs. */
static void fix_crcs(uint8_t *d, size_t size)
{
    size_t at = 0;
    while (size - at >= WF_PACKET_HEADER_SIZE) {
        uint8_t *h = d + at;
        size_t len = le32(h + 32), avail = size - at - WF_PACKET_HEADER_SIZE;
        if (len > avail) len = avail;
        put_le32(h + 40, (uint32_t)crc32(0, h + WF_PACKET_HEADER_SIZE, (uInt)len));
        put_le32(h + 44, (uint32_t)crc32(0, h, 44));
        at += WF_PACKET_HEADER_SIZE + len;
    }
}

static void check_no_tmp(const char *out)
{
    DIR *d = opendir(out);
    if (!d) abort();
    struct dirent *e;
    while ((e = readdir(d))) {
        size_t n = strlen(e->d_name);
        if (n > 4 && !strcmp(e->d_name + n - 4, ".tmp")) {
            fprintf(stderr, "fuzz_packets: %s left behind: %s\n", e->d_name, wf_error_message());
            abort();
        }
    }
    closedir(d);
}

static void assemble(const uint8_t *data, size_t size, const char *out)
{
    source s = {.data = data, .size = size};
    wf_assemble_options opt = {.out_dir = out, .quiet = 1};
    char last[4096];
    (void)wf_assemble_source(read_mem, &s, "fuzz", &opt, last, sizeof last);
    check_no_tmp(out);
    fz_clean("out");
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char out[4096];
    snprintf(out, sizeof out, "%s/out", fz_dir());
    mkdir(out, 0777);
    assemble(data, size, out);
    uint8_t *copy = malloc(size ? size : 1);
    if (!copy) return 0;
    memcpy(copy, data, size);
    fix_crcs(copy, size);
    if (memcmp(copy, data, size)) assemble(copy, size, out);
    free(copy);
    return 0;
}
