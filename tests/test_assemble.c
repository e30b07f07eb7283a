/* Assembler: packet streams built here with the real packer, assembled, read back. */
#include <dirent.h>
#include <fitsio.h>
#include <math.h>
#include <signal.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

#include "hal/arena.h"
#include "hal/clock.h"
#include "hal/link.h"
#include "hal/packet.h"
#include "tests/testutil.h"
#include "tools/assemble.h"
#include "tools/rampfit.h"
#include "tools/surveyrun.h"

#define NCOLS 64
#define NROWS 96
#define TILE 16
#define NTILES (NROWS / TILE)
#define MAX_PACKETS 64
#define MA_READS_4 "1|2|3-4|5-9|10-17|18-25|26-33|34-43|44" /* Rev F table 4, as META spells it */

typedef struct spec {
    int single, compress, nonlinearity, cosmic;
    uint32_t exposure;
    uint16_t sca;
    double frame_time, gain, read_noise, nl_beta, exptime;
    int sat_x, sat_y, sat_val; /* one pixel's SATURATION value (sat_val < 0: none) */
    int low_x;                 /* single frame: this column at or below the bias (-1: none) */
    const char *extra;         /* hdr.* lines */
} spec;

typedef struct stream {
    unsigned char *data;
    size_t len;
    size_t off[MAX_PACKETS], size[MAX_PACKETS];
    int kind[MAX_PACKETS];
    uint32_t first_row[MAX_PACKETS];
    int n;
} stream;

static spec default_spec(void)
{
    spec s = {0};
    s.exposure = 42;
    s.sca = 7;
    s.frame_time = 2.0; /* with table 4 every t-bar is then a whole number of seconds */
    s.gain = 1.0;
    s.read_noise = 5.0;
    s.nl_beta = -6.0e-7;
    s.exptime = 100.0;
    s.sat_val = -1;
    s.low_x = -1;
    return s;
}

/* Whole e-/s, so that rate x t-bar is an exact ADU count at gain 1. */
static double true_rate(int x, int y) { return 1.0 + (double)((x + 7 * y) % 700); }

static void clock_4(double frame_time, wf_clock *clk)
{
    ck_assert_int_eq(wf_ma_builtin("4", &clk->ma), WF_OK);
    clk->frame_time = frame_time;
}

static void send(wf_packer *pk, const wf_link *link, wf_link_memory *mem, stream *s,
                 const spec *sp, int kind, uint32_t first_row, uint32_t rows, uint32_t ncols,
                 uint32_t nplanes, const void *raw, size_t raw_len)
{
    ck_assert_int_lt(s->n, MAX_PACKETS);
    wf_packet_header h = {0};
    h.kind = (uint16_t)kind;
    h.exposure = sp->exposure;
    h.sca = sp->sca;
    h.first_row = first_row;
    h.row_count = rows;
    h.ncols = ncols;
    h.nplanes = nplanes;
    size_t before = mem->len;
    ck_assert_int_eq(wf_packer_send(pk, link, &h, raw, raw_len), WF_OK);
    s->off[s->n] = before;
    s->size[s->n] = mem->len - before;
    s->kind[s->n] = kind;
    s->first_row[s->n] = first_row;
    s->n++;
}

/* META, then per tile RESULTANTS (or SINGLE), COSMIC where it has hits, SATURATION; END. */
static void build(const spec *sp, stream *s)
{
    memset(s, 0, sizeof *s);
    wf_clock clk;
    clock_4(sp->frame_time, &clk);
    const int nres = clk.ma.nresultants;
    size_t max_raw = (size_t)nres * TILE * NCOLS * 2 + 8192;
    size_t bytes = wf_packer_arena_need(max_raw, sp->compress) + 4096;
    void *block = malloc(bytes);
    ck_assert_ptr_nonnull(block);
    wf_arena arena;
    ck_assert_int_eq(wf_arena_init(&arena, block, bytes, "test packer"), WF_OK);
    wf_packer pk;
    ck_assert_int_eq(wf_packer_init(&pk, &arena, max_raw, sp->compress), WF_OK);
    wf_link_memory mem;
    wf_link link;
    ck_assert_int_eq(wf_link_memory_open(&mem, &link), WF_OK);

    char meta[4096];
    int n = snprintf(meta, sizeof meta,
                     "ncols = %d\nnrows = %d\nmode = %s\nsampling = per-read\nexposure = %u\n"
                     "sca = %u\nseed = 18446744073709551615\nframe_time = %.17g\nexptime = %.17g\n"
                     "ma_table = 4\nma_reads = %s\ngain = %.17g\nread_noise = %.17g\n"
                     "dark_current = 0.015\nfull_well = 100000\nadc_max = 65535\n"
                     "saturation_adu = 65535\nnl_beta = %.17g\n"
                     "effects = photon,reciprocity,dark,%sipc,read_noise,quantize,saturation%s\n"
                     "%s",
                     NCOLS, NROWS, sp->single ? "single" : "ramp", sp->exposure, sp->sca,
                     sp->frame_time, sp->single ? sp->exptime : wf_clock_exposure_time(&clk),
                     MA_READS_4, sp->gain, sp->read_noise, sp->nl_beta,
                     sp->nonlinearity ? "nonlinearity," : "", sp->single ? "" : ",cosmic",
                     sp->extra ? sp->extra : "");
    ck_assert(n > 0 && (size_t)n < sizeof meta);
    send(&pk, &link, &mem, s, sp, WF_PK_META, 0, 0, 0, 0, meta, (size_t)n);

    uint16_t *res = malloc((size_t)nres * TILE * NCOLS * sizeof *res);
    float *single = malloc((size_t)TILE * NCOLS * sizeof *single);
    uint8_t sat[TILE * NCOLS];
    ck_assert(res && single);
    for (int t = 0; t < NTILES; t++) {
        int y0 = t * TILE;
        for (int y = y0; y < y0 + TILE; y++)
            for (int x = 0; x < NCOLS; x++) {
                size_t i = (size_t)(y - y0) * NCOLS + (size_t)x;
                double rate = true_rate(x, y);
                for (int r = 0; r < nres; r++) {
                    double q = rate * wf_clock_resultant_time(&clk, r);
                    if (sp->nonlinearity) q += sp->nl_beta * q * q;
                    res[(size_t)r * TILE * NCOLS + i] = (uint16_t)nearbyint(q / sp->gain);
                }
                single[i] = (float)(rate * sp->exptime / sp->gain);
                if (x == sp->low_x) single[i] = -1.5f * (float)(y % 5); /* 0, -0 and below */
                sat[i] = x == sp->sat_x && y == sp->sat_y && sp->sat_val >= 0 ? (uint8_t)sp->sat_val : 255;
            }
        if (sp->single)
            send(&pk, &link, &mem, s, sp, WF_PK_SINGLE, (uint32_t)y0, TILE, NCOLS, 1, single,
                 (size_t)TILE * NCOLS * sizeof *single);
        else
            send(&pk, &link, &mem, s, sp, WF_PK_RESULTANTS, (uint32_t)y0, TILE, NCOLS,
                 (uint32_t)nres, res, (size_t)nres * TILE * NCOLS * sizeof *res);
        if (sp->cosmic && (t == 1 || t == 4)) {
            /* ids out of order within and across packets: the table must come out sorted */
            wf_cosmic_record cr[2] = {
                {3.0f, (float)y0 + 1, 5.5f, (float)y0 + 2, 1234.5f, 7, t == 1 ? 9u : 2u, 0},
                {10.0f, (float)y0 + 3, 10.0f, (float)y0 + 3, 99.0f, 20, t == 1 ? 4u : 6u, 0}};
            send(&pk, &link, &mem, s, sp, WF_PK_COSMIC, (uint32_t)y0, TILE, NCOLS, 2, cr, sizeof cr);
        }
        send(&pk, &link, &mem, s, sp, WF_PK_SATURATION, (uint32_t)y0, TILE, NCOLS, 1, sat, sizeof sat);
    }
    send(&pk, &link, &mem, s, sp, WF_PK_END, 0, NROWS, NCOLS, 0, NULL, 0);

    s->len = mem.len;
    s->data = malloc(mem.len);
    ck_assert_ptr_nonnull(s->data);
    memcpy(s->data, mem.data, mem.len);
    wf_link_memory_close(&mem);
    wf_packer_close(&pk);
    free(block);
    free(res);
    free(single);
}

/* The stream's packets in the given order (indices into s), into a file. */
static char *write_stream(const stream *s, const int *order, int n, const char *dir, const char *name)
{
    static char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    FILE *f = fopen(path, "wb");
    ck_assert_ptr_nonnull(f);
    for (int i = 0; i < n; i++)
        ck_assert_uint_eq(fwrite(s->data + s->off[order[i]], 1, s->size[order[i]], f), s->size[order[i]]);
    ck_assert_int_eq(fclose(f), 0);
    return path;
}

static int identity(int *order, const stream *s)
{
    for (int i = 0; i < s->n; i++) order[i] = i;
    return s->n;
}

/* META stays first and END last; everything between in a pseudo-random order of the seed,
 * then (reverse) fully reversed. */
static void shuffle(int *order, int n, uint32_t seed, int reverse)
{
    uint32_t lcg = seed;
    for (int i = n - 2; i > 1; i--) {
        lcg = lcg * 1664525u + 1013904223u;
        int j = 1 + (int)((lcg >> 8) % (uint32_t)i);
        int t = order[i]; order[i] = order[j]; order[j] = t;
    }
    if (reverse)
        for (int i = 1, j = n - 2; i < j; i++, j--) { int t = order[i]; order[i] = order[j]; order[j] = t; }
}

static wf_status assemble_with(const char *path, const wf_assemble_options *opt, char *out_path)
{
    FILE *in = fopen(path, "rb");
    ck_assert_ptr_nonnull(in);
    char last[4096];
    wf_status st = wf_assemble_stream(in, path, opt, last, sizeof last);
    fclose(in);
    if (out_path) strcpy(out_path, last);
    return st;
}

static wf_status assemble_file(const char *path, const char *out_dir, char *out_path)
{
    FILE *in = fopen(path, "rb");
    ck_assert_ptr_nonnull(in);
    wf_assemble_options opt = {.out_dir = out_dir, .quiet = 1};
    char last[4096];
    wf_status st = wf_assemble_stream(in, path, &opt, last, sizeof last);
    fclose(in);
    if (out_path) strcpy(out_path, last);
    return st;
}

static int count_entries(const char *dir)
{
    DIR *d = opendir(dir);
    ck_assert_ptr_nonnull(d);
    int n = 0;
    for (struct dirent *e; (e = readdir(d));)
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) n++;
    closedir(d);
    return n;
}

static unsigned char *slurp(const char *path, size_t *len)
{
    FILE *f = fopen(path, "rb");
    ck_assert_ptr_nonnull(f);
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    unsigned char *buf = malloc((size_t)n + 1);
    ck_assert_ptr_nonnull(buf);
    ck_assert_uint_eq(fread(buf, 1, (size_t)n, f), (size_t)n);
    fclose(f);
    *len = (size_t)n;
    return buf;
}

static fitsfile *open_fits(const char *path)
{
    fitsfile *f;
    int status = 0;
    fits_open_diskfile(&f, path, READONLY, &status);
    ck_assert_msg(status == 0, "cannot open %s: cfitsio %d", path, status);
    return f;
}

static void read_image(fitsfile *f, const char *extname, int type, long nelem, void *out)
{
    int status = 0, anynul = 0;
    fits_movnam_hdu(f, ANY_HDU, (char *)extname, 0, &status);
    ck_assert_msg(status == 0, "no HDU %s", extname);
    long first[3] = {1, 1, 1};
    fits_read_pix(f, type, first, nelem, NULL, out, &anynul, &status);
    ck_assert_int_eq(status, 0);
}

/* Every HDU's CHECKSUM and DATASUM verify with cfitsio; returns the HDU count. */
static int assert_checksums(const char *path)
{
    fitsfile *f = open_fits(path);
    int status = 0, nhdu = 0;
    fits_get_num_hdus(f, &nhdu, &status);
    for (int i = 1; i <= nhdu; i++) {
        int dstat = 0, hstat = 0;
        fits_movabs_hdu(f, i, NULL, &status);
        fits_verify_chksum(f, &dstat, &hstat, &status);
        ck_assert_int_eq(status, 0);
        ck_assert_msg(dstat == 1 && hstat == 1, "%s HDU %d checksum: data %d, hdu %d", path, i,
                      dstat, hstat);
    }
    fits_close_file(f, &status);
    return nhdu;
}

/* A directory pair: stream files go to in, products to out (so "no output" is countable). */
static void dirs(char *in, char *out)
{
    strcpy(in, wf_test_tmpdir());
    strcpy(out, wf_test_tmpdir());
}

START_TEST(test_linear_ramp)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    spec sp = default_spec();
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    const char *path = write_stream(&s, order, n, in, "s.wfip");
    ck_assert_msg(assemble_file(path, out, fits) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(count_entries(out), 1);
    ck_assert_ptr_nonnull(strstr(fits, "wfisim_e000042_sca07.fits"));

    fitsfile *f = open_fits(fits);
    static float sci[NROWS * NCOLS], err[NROWS * NCOLS];
    static uint32_t dq[NROWS * NCOLS];
    static uint16_t cube[9 * NROWS * NCOLS];
    read_image(f, "SCI", TFLOAT, NROWS * NCOLS, sci);
    read_image(f, "ERR", TFLOAT, NROWS * NCOLS, err);
    read_image(f, "DQ", TUINT, NROWS * NCOLS, dq);
    read_image(f, "RESULTANTS", TUSHORT, 9 * NROWS * NCOLS, cube);
    wf_clock clk;
    clock_4(sp.frame_time, &clk);
    for (int y = 0; y < NROWS; y++)
        for (int x = 0; x < NCOLS; x++) {
            size_t i = (size_t)y * NCOLS + (size_t)x;
            double rate = true_rate(x, y);
            ck_assert_msg(fabs(sci[i] - rate) <= 1e-4 * rate, "SCI(%d,%d) = %.7g, rate %g", x, y,
                          sci[i], rate);
            ck_assert_msg(dq[i] == 0, "DQ(%d,%d) = %u", x, y, dq[i]);
            ck_assert(isfinite(err[i]) && err[i] > 0);
            for (int r = 0; r < 9; r++)
                ck_assert_uint_eq(cube[(size_t)r * NROWS * NCOLS + i],
                                  (uint16_t)(rate * wf_clock_resultant_time(&clk, r)));
        }
    int status = 0;
    long ncr = -1;
    fits_movnam_hdu(f, BINARY_TBL, "COSMICRAYS", 0, &status);
    fits_get_num_rows(f, &ncr, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(ncr, 0); /* cosmic rays on, none hit: an empty table, not a missing one */
    fits_close_file(f, &status);
    ck_assert_int_eq(assert_checksums(fits), 6);
    free(s.data);
}
END_TEST

START_TEST(test_shuffled_is_identical)
{
    char in[1024], out1[1024], out2[1024], fits1[4096], fits2[4096];
    dirs(in, out1);
    strcpy(out2, wf_test_tmpdir());
    spec sp = default_spec();
    sp.cosmic = 1;
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    ck_assert_int_eq(assemble_file(write_stream(&s, order, n, in, "a.wfip"), out1, fits1), WF_OK);
    /* META stays first and END last; everything between in a fixed pseudo-random order,
     * and also fully reversed (every SATURATION before its RESULTANTS) */
    for (int pass = 0; pass < 2; pass++) {
        shuffle(order, n, 12345u, pass == 1);
        int moved = 0;
        for (int i = 0; i < n; i++) moved += order[i] != i;
        ck_assert_int_gt(moved, n / 2);
        char name[32];
        snprintf(name, sizeof name, "b%d.wfip", pass);
        ck_assert_msg(assemble_file(write_stream(&s, order, n, in, name), out2, fits2) == WF_OK, "%s",
                      wf_error_message());
        wf_test_assert_same_file(fits1, fits2);
        n = identity(order, &s);
        ck_assert_int_eq(remove(fits2), 0);
    }
    /* the cosmic-ray table comes sorted by id whatever the packet order */
    fitsfile *f = open_fits(fits1);
    int status = 0;
    long nrows = 0;
    fits_movnam_hdu(f, BINARY_TBL, "COSMICRAYS", 0, &status);
    fits_get_num_rows(f, &nrows, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(nrows, 4);
    uint32_t ids[4], reads[4];
    float el[4];
    fits_read_col(f, TUINT, 7, 1, 1, 4, NULL, ids, NULL, &status);
    fits_read_col(f, TUINT, 6, 1, 1, 4, NULL, reads, NULL, &status);
    fits_read_col(f, TFLOAT, 5, 1, 1, 4, NULL, el, NULL, &status);
    ck_assert_int_eq(status, 0);
    ck_assert(ids[0] == 2 && ids[1] == 4 && ids[2] == 6 && ids[3] == 9);
    ck_assert(reads[0] == 7 && reads[1] == 20 && el[0] == 1234.5f && el[1] == 99.0f);
    fits_close_file(f, &status);
    free(s.data);
}
END_TEST

START_TEST(test_compressed_is_identical)
{
    char in[1024], out1[1024], out2[1024], fits1[4096], fits2[4096];
    dirs(in, out1);
    strcpy(out2, wf_test_tmpdir());
    spec sp = default_spec();
    sp.cosmic = 1;
    stream plain, packed;
    build(&sp, &plain);
    sp.compress = 1;
    build(&sp, &packed);
    ck_assert_uint_lt(packed.len, plain.len);
    int order[MAX_PACKETS], n = identity(order, &plain);
    ck_assert_int_eq(assemble_file(write_stream(&plain, order, n, in, "p.wfip"), out1, fits1), WF_OK);
    n = identity(order, &packed);
    ck_assert_msg(assemble_file(write_stream(&packed, order, n, in, "z.wfip"), out2, fits2) == WF_OK,
                  "%s", wf_error_message());
    wf_test_assert_same_file(fits1, fits2);
    free(plain.data);
    free(packed.data);
}
END_TEST

/* Corruption cases, each applied to a fresh copy of the stream. */
enum { FLIP_PAYLOAD, FLIP_HEADER, DROP_TILE, DUP_TILE, CUT_MID, CUT_BEFORE_END, NO_META,
       SHAPE_MISMATCH, HDR_CONFLICT, HDR_BAD_NAME, META_TWICE, N_DAMAGE };

static int find_packet(const stream *s, int kind, uint32_t first_row)
{
    for (int i = 0; i < s->n; i++)
        if (s->kind[i] == kind && s->first_row[i] == first_row) return i;
    ck_abort_msg("no packet of kind %d at row %u", kind, first_row);
    return -1;
}

START_TEST(test_damage)
{
    const int damage = _i;
    char in[1024], out[1024];
    dirs(in, out);
    spec sp = default_spec();
    sp.compress = damage == FLIP_PAYLOAD; /* a flipped deflate byte must not slip through */
    if (damage == HDR_CONFLICT) sp.extra = "hdr.FILTER = J129\nhdr.exptime = 5 / clash\n";
    if (damage == HDR_BAD_NAME) sp.extra = "hdr.OBSERVATORY = Roman\n";
    if (damage == META_TWICE) sp.extra = "gain = 2\n";
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    const char *expect = NULL;
    size_t cut = 0;
    int res2 = find_packet(&s, WF_PK_RESULTANTS, 2 * TILE), sat2 = find_packet(&s, WF_PK_SATURATION, 2 * TILE);
    switch (damage) {
    case FLIP_PAYLOAD:
        s.data[s.off[res2] + WF_PACKET_HEADER_SIZE + s.size[res2] / 2] ^= 0x10;
        expect = "CRC";
        break;
    case FLIP_HEADER:
        s.data[s.off[sat2] + 21] ^= 0x01; /* row_count */
        expect = "header CRC";
        break;
    case DROP_TILE: {
        int k = 0;
        for (int i = 0; i < n; i++)
            if (i != res2 && i != sat2) order[k++] = i;
        n = k;
        expect = "rows 32-47 missing";
        break;
    }
    case DUP_TILE:
        for (int i = n; i > res2 + 2; i--) order[i] = order[i - 1];
        order[res2 + 2] = res2;
        n++;
        expect = "duplicate: rows 32-47";
        break;
    case CUT_MID:
        cut = s.off[res2] + s.size[res2] / 2;
        expect = "truncated";
        break;
    case CUT_BEFORE_END:
        n--;
        expect = "without END";
        break;
    case NO_META:
        for (int i = 0; i < n - 1; i++) order[i] = order[i + 1];
        n--;
        expect = "before META";
        break;
    case SHAPE_MISMATCH: {
        /* a META saying 63 columns against packets of 64 */
        spec sp2 = sp;
        stream s2;
        sp2.extra = NULL;
        build(&sp2, &s2);
        char *meta = (char *)s2.data + WF_PACKET_HEADER_SIZE;
        char *p = strstr(meta, "ncols = 64");
        ck_assert_ptr_nonnull(p);
        p[9] = '3';
        /* re-seal the META payload CRC and header so only the shape is wrong */
        wf_packet_header h;
        ck_assert_int_eq(wf_packet_header_read(s2.data, &h), WF_OK);
        h.payload_crc = (uint32_t)crc32(0L, s2.data + WF_PACKET_HEADER_SIZE, h.payload_len);
        wf_packet_header_write(&h, s2.data);
        free(s.data);
        s = s2;
        expect = "64 columns, META says 63";
        break;
    }
    case HDR_CONFLICT: expect = "hdr.EXPTIME repeats a keyword"; break;
    case HDR_BAD_NAME: expect = "not a FITS keyword"; break;
    case META_TWICE: expect = "'gain' given twice"; break;
    }
    const char *path = write_stream(&s, order, n, in, "bad.wfip");
    if (cut) ck_assert_int_eq(truncate(path, (off_t)cut), 0);
    wf_status st = assemble_file(path, out, NULL);
    const char *msg = wf_error_message();
    if (getenv("WF_TEST_VERBOSE")) printf("damage %d: %s\n", damage, msg);
    ck_assert_int_ne(st, WF_OK);
    ck_assert_msg(strstr(msg, path) != NULL, "message does not name the stream: %s", msg);
    ck_assert_msg(strstr(msg, expect) != NULL, "damage %d: expected '%s' in: %s", damage, expect, msg);
    ck_assert_msg(count_entries(out) == 0, "damage %d left a file behind", damage);
    free(s.data);
}
END_TEST

START_TEST(test_saturated_pixel)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    for (int v = 0; v < 2; v++) {
        spec sp = default_spec();
        sp.sat_x = 5;
        sp.sat_y = 50;
        sp.sat_val = v == 0 ? 3 : 0; /* saturated from resultant 3 on; saturated from the start */
        stream s;
        build(&sp, &s);
        int order[MAX_PACKETS], n = identity(order, &s);
        /* the saturation map after its resultants and before: both paths of the pairing */
        if (v == 1) {
            int r = find_packet(&s, WF_PK_RESULTANTS, 48), t = find_packet(&s, WF_PK_SATURATION, 48);
            order[r] = t;
            order[t] = r;
        }
        ck_assert_msg(assemble_file(write_stream(&s, order, n, in, "sat.wfip"), out, fits) == WF_OK,
                      "%s", wf_error_message());
        fitsfile *f = open_fits(fits);
        static uint32_t dq[NROWS * NCOLS];
        static float sci[NROWS * NCOLS];
        read_image(f, "DQ", TUINT, NROWS * NCOLS, dq);
        read_image(f, "SCI", TFLOAT, NROWS * NCOLS, sci);
        int status = 0;
        fits_close_file(f, &status);
        size_t i = 50 * NCOLS + 5;
        ck_assert_msg(dq[i] & WF_DQ_SATURATED, "DQ = %u", dq[i]);
        if (v == 1) ck_assert(dq[i] & WF_DQ_DO_NOT_USE);
        else ck_assert_msg(fabs(sci[i] - true_rate(5, 50)) < 1e-4 * true_rate(5, 50), "%g", sci[i]);
        ck_assert_uint_eq(dq[i - 1], 0);
        ck_assert_uint_eq(dq[i + 1], 0);
        ck_assert_int_eq(remove(fits), 0);
        free(s.data);
    }
}
END_TEST

START_TEST(test_nonlinearity_corrected)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    spec sp = default_spec();
    sp.nonlinearity = 1;
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    ck_assert_msg(assemble_file(write_stream(&s, order, n, in, "nl.wfip"), out, fits) == WF_OK, "%s",
                  wf_error_message());
    fitsfile *f = open_fits(fits);
    static float sci[NROWS * NCOLS];
    read_image(f, "SCI", TFLOAT, NROWS * NCOLS, sci);
    int status = 0;
    fits_close_file(f, &status);
    double worst = 0;
    for (int y = 0; y < NROWS; y++)
        for (int x = 0; x < NCOLS; x++) {
            double rate = true_rate(x, y), rel = fabs(sci[y * NCOLS + x] - rate) / rate;
            if (rate >= 100 && rel > worst) worst = rel;
        }
    /* uncorrected, the brightest ramps here would read ~4% low; rounding to ADU is what is left */
    ck_assert_msg(worst < 2e-4, "worst relative error %g", worst);
    free(s.data);
}
END_TEST

START_TEST(test_single_frame)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    spec sp = default_spec();
    sp.single = 1;
    sp.gain = 2.0;
    sp.sat_x = 63;
    sp.sat_y = 95;
    sp.sat_val = 0;
    sp.low_x = 5;
    sp.extra = "bias = 0.37\n"; /* not a whole ADU: adu - bias is rounded in both paths */
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    ck_assert_msg(assemble_file(write_stream(&s, order, n, in, "single.wfip"), out, fits) == WF_OK,
                  "%s", wf_error_message());
    fitsfile *f = open_fits(fits);
    static float sci[NROWS * NCOLS], err[NROWS * NCOLS];
    static uint32_t dq[NROWS * NCOLS];
    read_image(f, "SCI", TFLOAT, NROWS * NCOLS, sci);
    read_image(f, "ERR", TFLOAT, NROWS * NCOLS, err);
    read_image(f, "DQ", TUINT, NROWS * NCOLS, dq);
    int status = 0, nhdu = 0;
    fits_get_num_hdus(f, &nhdu, &status);
    ck_assert_int_eq(nhdu, 4); /* no RESULTANTS in single-frame mode */
    fits_close_file(f, &status);
    ck_assert_int_eq(assert_checksums(fits), 4);
    for (int i = 0; i < NROWS * NCOLS; i++) {
        int x = i % NCOLS, y = i / NCOLS;
        double rate = true_rate(x, y), q = rate * sp.exptime - 0.37 * sp.gain; /* bias off */
        if (x != sp.low_x) {
            ck_assert(fabs(sci[i] - q / sp.exptime) <= 1e-5 * rate);
            ck_assert(fabs(err[i] - sqrt(q + 25.0) / sp.exptime) <= 1e-5 * err[i]);
        } else { /* below the bias: no Poisson term */
            ck_assert(sci[i] < 0.0f);
            ck_assert(err[i] == (float)(5.0 / sp.exptime));
        }
        /* to the bit, the assembler's formula in double, whichever code path computed it */
        float adu = x == sp.low_x ? -1.5f * (float)(y % 5) : (float)(rate * sp.exptime / sp.gain);
        double qq = (adu - 0.37) * sp.gain;
        ck_assert(sci[i] == (float)(qq * (1.0 / sp.exptime)));
        ck_assert(err[i] == (float)(sqrt((qq > 0 ? qq : 0) + 25.0) * (1.0 / sp.exptime)));
        ck_assert_uint_eq(dq[i], i == NROWS * NCOLS - 1 ? WF_DQ_SATURATED : 0u);
    }
    free(s.data);
}
END_TEST

START_TEST(test_headers_and_checksums)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    spec sp = default_spec();
    sp.cosmic = 1;
    sp.extra = "hdr.FILTER = Y106 / optical element\nhdr.MJD-OBS = 61000.25 / [d] start\n"
               "hdr.VISIT = 17\nhdr.OBJECT = 'deep field / tier' / quoted\n";
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    ck_assert_msg(assemble_file(write_stream(&s, order, n, in, "h.wfip"), out, fits) == WF_OK, "%s",
                  wf_error_message());
    fitsfile *f = open_fits(fits);
    int status = 0, nhdu = 0;
    fits_get_num_hdus(f, &nhdu, &status);
    ck_assert_int_eq(nhdu, 6);
    const char *names[] = {"", "SCI", "ERR", "DQ", "RESULTANTS", "COSMICRAYS"};
    const int naxis[] = {0, 2, 2, 2, 3, 2};
    for (int i = 1; i <= nhdu; i++) {
        int type, dstat = 0, hstat = 0, nax = -1;
        fits_movabs_hdu(f, i, &type, &status);
        ck_assert_int_eq(status, 0);
        if (i > 1) {
            char ext[FLEN_VALUE];
            fits_read_key_str(f, "EXTNAME", ext, NULL, &status);
            ck_assert_str_eq(ext, names[i - 1]);
        }
        fits_read_key(f, TINT, "NAXIS", &nax, NULL, &status);
        ck_assert_int_eq(nax, naxis[i - 1]);
        fits_verify_chksum(f, &dstat, &hstat, &status);
        ck_assert_int_eq(status, 0);
        ck_assert_msg(dstat == 1 && hstat == 1, "HDU %d checksum: data %d, hdu %d", i, dstat, hstat);
        char comment[FLEN_COMMENT];
        fits_read_key_str(f, "CHECKSUM", (char[FLEN_VALUE]){0}, comment, &status);
        ck_assert_str_eq(comment, "HDU checksum"); /* no time stamp */
    }
    long naxes[3] = {0};
    fits_movnam_hdu(f, IMAGE_HDU, "RESULTANTS", 0, &status);
    fits_get_img_size(f, 3, naxes, &status);
    ck_assert(naxes[0] == NCOLS && naxes[1] == NROWS && naxes[2] == 9);
    char str[FLEN_VALUE];
    fits_read_key_str(f, "BUNIT", str, NULL, &status);
    ck_assert_str_eq(str, "adu");
    fits_movnam_hdu(f, IMAGE_HDU, "SCI", 0, &status);
    fits_get_img_size(f, 2, naxes, &status);
    ck_assert(naxes[0] == NCOLS && naxes[1] == NROWS);

    fits_movabs_hdu(f, 1, NULL, &status);
    long v;
    double d;
    fits_read_key(f, TLONG, "EXPOSURE", &v, NULL, &status);
    ck_assert_int_eq(v, 42);
    fits_read_key(f, TLONG, "SCA", &v, NULL, &status);
    ck_assert_int_eq(v, 7);
    fits_read_key(f, TLONG, "NRESULT", &v, NULL, &status);
    ck_assert_int_eq(v, 9);
    fits_read_key(f, TLONG, "VISIT", &v, NULL, &status);
    ck_assert_int_eq(v, 17);
    fits_read_key(f, TDOUBLE, "FRAMTIME", &d, NULL, &status);
    ck_assert(d == 2.0);
    fits_read_key(f, TDOUBLE, "EXPTIME", &d, NULL, &status);
    ck_assert(d == 88.0);
    fits_read_key(f, TDOUBLE, "MJD-OBS", &d, NULL, &status);
    ck_assert(d == 61000.25);
    fits_read_key(f, TDOUBLE, "DARKCUR", &d, NULL, &status);
    ck_assert(d == 0.015);
    char comment[FLEN_COMMENT];
    fits_read_key_str(f, "FILTER", str, comment, &status);
    ck_assert_str_eq(str, "Y106");
    ck_assert_str_eq(comment, "optical element");
    fits_read_key_str(f, "OBJECT", str, NULL, &status);
    ck_assert_str_eq(str, "deep field / tier");
    fits_read_key_str(f, "MODE", str, NULL, &status);
    ck_assert_str_eq(str, "ramp");
    fits_read_key_str(f, "MA_TABLE", str, NULL, &status);
    ck_assert_str_eq(str, "4");
    fits_read_key_str(f, "MAREAD03", str, NULL, &status);
    ck_assert_str_eq(str, "3-4");
    fits_read_key_str(f, "MAREAD09", str, NULL, &status);
    ck_assert_str_eq(str, "44");
    unsigned long long seed = 0;
    fits_read_key(f, TULONGLONG, "SEED", &seed, NULL, &status);
    ck_assert(seed == 18446744073709551615ull);
    char *effects = NULL;
    fits_read_key_longstr(f, "EFFECTS", &effects, NULL, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_str_eq(effects, "photon,reciprocity,dark,ipc,read_noise,quantize,saturation,cosmic");
    fits_free_memory(effects, &status);
    int exists = 1;
    char card[FLEN_CARD];
    fits_read_card(f, "DATE", card, &status);
    exists = status != KEY_NO_EXIST;
    ck_assert(!exists); /* nothing time-dependent in the product */
    status = 0;
    fits_close_file(f, &status);
    free(s.data);
}
END_TEST

START_TEST(test_two_exposures)
{
    char in[1024], out[1024], fits[4096];
    dirs(in, out);
    spec a = default_spec(), b = default_spec();
    b.exposure = 43;
    b.sca = 18;
    stream sa, sb;
    build(&a, &sa);
    build(&b, &sb);
    char path[4096];
    snprintf(path, sizeof path, "%s/two.wfip", in);
    FILE *f = fopen(path, "wb");
    ck_assert_uint_eq(fwrite(sa.data, 1, sa.len, f), sa.len);
    ck_assert_uint_eq(fwrite(sb.data, 1, sb.len, f), sb.len);
    fclose(f);
    ck_assert_msg(assemble_file(path, out, fits) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(count_entries(out), 2);
    ck_assert_ptr_nonnull(strstr(fits, "wfisim_e000043_sca18.fits"));
    char first[4096];
    snprintf(first, sizeof first, "%s/wfisim_e000042_sca07.fits", out);
    ck_assert_int_eq(access(first, R_OK), 0);
    free(sa.data);
    free(sb.data);
}
END_TEST

/* A file-size limit stands in for a full disk: cfitsio's writes fail part way. */
START_TEST(test_disk_full)
{
    char in[1024], out[1024];
    dirs(in, out);
    spec sp = default_spec();
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    const char *path = write_stream(&s, order, n, in, "full.wfip");
    struct rlimit old, lim;
    ck_assert_int_eq(getrlimit(RLIMIT_FSIZE, &old), 0);
    lim = old;
    lim.rlim_cur = 40000; /* the product is ~170 kB */
    signal(SIGXFSZ, SIG_IGN);
    ck_assert_int_eq(setrlimit(RLIMIT_FSIZE, &lim), 0);
    wf_status st = assemble_file(path, out, NULL);
    setrlimit(RLIMIT_FSIZE, &old);
    ck_assert_int_ne(st, WF_OK);
    ck_assert_msg(strstr(wf_error_message(), "cfitsio") != NULL, "%s", wf_error_message());
    ck_assert_int_eq(count_entries(out), 0);
    free(s.data);
}
END_TEST

/* products.compress / quantize_level / resultants: each mode against the plain product. */
enum { MODE_RICE, MODE_RICE_DROP, MODE_PLAIN_DROP, MODE_LOSSLESS, N_MODES };

START_TEST(test_product_modes)
{
    const int mode = _i;
    char in[1024], ref_dir[1024], out[1024], ref[4096], fits[4096], again[4096];
    dirs(in, ref_dir);
    strcpy(out, wf_test_tmpdir());
    spec sp = default_spec();
    sp.cosmic = 1;
    sp.sat_x = 5, sp.sat_y = 40, sp.sat_val = 3;
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    const char *path = write_stream(&s, order, n, in, "m.wfip");
    ck_assert_int_eq(assemble_file(path, ref_dir, ref), WF_OK);
    wf_assemble_options opt = {.out_dir = out, .quiet = 1, .compress = mode != MODE_PLAIN_DROP,
                               .quantize_level = mode == MODE_LOSSLESS ? 0 : 16,
                               .drop_resultants = mode == MODE_RICE_DROP || mode == MODE_PLAIN_DROP};
    ck_assert_msg(assemble_with(path, &opt, fits) == WF_OK, "%s", wf_error_message());
    ck_assert_int_eq(count_entries(out), 1); /* no part file left behind */
    const int want_hdus = opt.drop_resultants ? 5 : 6;
    ck_assert_int_eq(assert_checksums(fits), want_hdus);
    ck_assert_msg(wf_survey_product_ok(fits), "%s", wf_error_message());

    /* the same bytes whatever the packet order: shuffled, and every SATURATION first */
    for (int pass = 0; pass < 2; pass++) {
        shuffle(order, n, 999u + (uint32_t)pass, pass == 1);
        char dir2[1024];
        strcpy(dir2, wf_test_tmpdir());
        opt.out_dir = dir2;
        ck_assert_msg(assemble_with(write_stream(&s, order, n, in, "m2.wfip"), &opt, again) == WF_OK, "%s",
                      wf_error_message());
        wf_test_assert_same_file(fits, again);
        n = identity(order, &s);
    }

    fitsfile *a = open_fits(ref), *b = open_fits(fits);
    static float sa[NROWS * NCOLS], sb[NROWS * NCOLS];
    static uint32_t da[NROWS * NCOLS], db[NROWS * NCOLS];
    static uint16_t ca[9 * NROWS * NCOLS], cb[9 * NROWS * NCOLS];
    int status = 0;
    for (int k = 0; k < 2; k++) {
        const char *name = k ? "ERR" : "SCI";
        read_image(a, name, TFLOAT, NROWS * NCOLS, sa);
        read_image(b, name, TFLOAT, NROWS * NCOLS, sb);
        ck_assert_int_eq(fits_is_compressed_image(b, &status), opt.compress);
        for (int i = 0; i < NROWS * NCOLS; i++) {
            if (mode != MODE_RICE && mode != MODE_RICE_DROP) /* lossless or plain floats: the same bits */
                ck_assert_msg(!memcmp(&sa[i], &sb[i], sizeof sa[i]), "%s pixel %d: %.9g, plain %.9g", name, i,
                              sb[i], sa[i]);
            else /* a noise-free ramp: cfitsio's noise estimate, and the step, are tiny */
                ck_assert_msg(fabsf(sa[i] - sb[i]) <= 1e-3f * fabsf(sa[i]) + 1e-6f, "%s pixel %d: %.9g, plain %.9g",
                              name, i, sb[i], sa[i]);
        }
    }
    read_image(a, "DQ", TUINT, NROWS * NCOLS, da);
    read_image(b, "DQ", TUINT, NROWS * NCOLS, db);
    ck_assert_msg(!memcmp(da, db, sizeof da), "DQ changed");
    ck_assert_uint_eq(db[40 * NCOLS + 5] & WF_DQ_SATURATED, WF_DQ_SATURATED);
    fits_movnam_hdu(b, BINARY_TBL, "COSMICRAYS", 0, &status);
    ck_assert_int_eq(status, 0);
    if (opt.drop_resultants) {
        fits_movnam_hdu(b, ANY_HDU, "RESULTANTS", 0, &status);
        ck_assert_int_eq(status, BAD_HDU_NUM);
        status = 0;
        fits_clear_errmsg();
    } else {
        read_image(a, "RESULTANTS", TUSHORT, 9 * NROWS * NCOLS, ca);
        read_image(b, "RESULTANTS", TUSHORT, 9 * NROWS * NCOLS, cb);
        ck_assert_msg(!memcmp(ca, cb, sizeof ca), "RESULTANTS changed");
    }
    fits_close_file(a, &status);
    fits_close_file(b, &status);

    /* a damaged compressed product is not taken as done by survey resume */
    size_t len;
    unsigned char *buf = slurp(fits, &len);
    buf[len - 3 * 2880 - 100] ^= 0x08; /* in the last image HDU's data */
    FILE *f = fopen(fits, "wb");
    ck_assert_uint_eq(fwrite(buf, 1, len, f), len);
    fclose(f);
    free(buf);
    ck_assert(!wf_survey_product_ok(fits));
    free(s.data);
}
END_TEST

static int python_with_astropy(void)
{
    return access("/usr/bin/python3", X_OK) == 0 &&
           system("/usr/bin/python3 -c 'import astropy' >/dev/null 2>&1") == 0;
}

START_TEST(test_astropy_reads_it)
{
    if (!python_with_astropy()) WF_SKIP("/usr/bin/python3 with astropy not available");
    if (access("tests/fits_check.py", R_OK) != 0) WF_SKIP("tests/fits_check.py not found (run from the repo)");
    char in[1024], out[1024], fits[4096], cmd[9000];
    dirs(in, out);
    spec sp = default_spec();
    sp.cosmic = 1;
    sp.extra = "hdr.FILTER = Y106 / optical element\n";
    stream s;
    build(&sp, &s);
    int order[MAX_PACKETS], n = identity(order, &s);
    ck_assert_msg(assemble_file(write_stream(&s, order, n, in, "py.wfip"), out, fits) == WF_OK, "%s",
                  wf_error_message());
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 tests/fits_check.py '%s' --shape %dx%d --nres 9 --cosmic 4",
             fits, NROWS, NCOLS);
    ck_assert_int_eq(system(cmd), 0);
    /* and the checker does notice a damaged file */
    size_t len;
    unsigned char *buf = slurp(fits, &len);
    buf[len / 2] ^= 0x40; /* inside the RESULTANTS data */
    char bad[4200];
    snprintf(bad, sizeof bad, "%s/bad.fits", out);
    FILE *f = fopen(bad, "wb");
    ck_assert_uint_eq(fwrite(buf, 1, len, f), len);
    fclose(f);
    free(buf);
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 tests/fits_check.py '%s' >/dev/null 2>&1", bad);
    ck_assert_int_ne(system(cmd), 0);
    /* tile-compressed, as a survey writes it: astropy reads it and its checksums verify */
    char out2[1024];
    strcpy(out2, wf_test_tmpdir());
    wf_assemble_options opt = {.out_dir = out2, .quiet = 1, .compress = 1, .quantize_level = 16};
    ck_assert_msg(assemble_with(write_stream(&s, order, n, in, "py.wfip"), &opt, fits) == WF_OK, "%s",
                  wf_error_message());
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 tests/fits_check.py '%s' --shape %dx%d --nres 9 --cosmic 4 --compressed",
             fits, NROWS, NCOLS);
    ck_assert_int_eq(system(cmd), 0);
    buf = slurp(fits, &len);
    buf[len / 2] ^= 0x40;
    f = fopen(bad, "wb");
    ck_assert_uint_eq(fwrite(buf, 1, len, f), len);
    fclose(f);
    free(buf);
    snprintf(cmd, sizeof cmd, "/usr/bin/python3 tests/fits_check.py '%s' --compressed >/dev/null 2>&1", bad);
    ck_assert_int_ne(system(cmd), 0);
    free(s.data);
}
END_TEST

static Suite *assemble_suite(void)
{
    Suite *s = suite_create("assemble");
    TCase *tc = tcase_create("assemble");
    tcase_set_timeout(tc, 120); /* sanitizer builds */
    tcase_add_test(tc, test_linear_ramp);
    tcase_add_test(tc, test_shuffled_is_identical);
    tcase_add_test(tc, test_compressed_is_identical);
    tcase_add_loop_test(tc, test_damage, 0, N_DAMAGE);
    tcase_add_test(tc, test_saturated_pixel);
    tcase_add_test(tc, test_nonlinearity_corrected);
    tcase_add_test(tc, test_single_frame);
    tcase_add_test(tc, test_headers_and_checksums);
    tcase_add_test(tc, test_two_exposures);
    tcase_add_test(tc, test_disk_full);
    tcase_add_test(tc, test_astropy_reads_it);
    tcase_add_loop_test(tc, test_product_modes, 0, N_MODES);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(assemble_suite()); }
