/* The streaming readout: determinism across tile heights and threads, fixed memory, flux
 * conservation, direct vs per-read sampling, saturation, single-frame order, cosmic rays,
 * replay. Streams are decoded here with the packet reader, independent of the assembler. */
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#include "firmware/cosmic.h"
#include "firmware/readout.h"
#include "hal/packet.h"
#include "hal/size.h"
#include "tests/testutil.h"
#include "tools/expose.h"

typedef struct decoded {
    int ncols, nrows, nres;
    uint16_t *res;    /* [nres][nrows][ncols] */
    float *single;    /* [nrows][ncols] */
    uint8_t *sat;     /* [nrows][ncols] */
    wf_cosmic_record *cr;
    int ncr;
    int rows_seen;
} decoded;

static void small_config(wf_readout_config *cfg, wf_clock *clock, int ncols, int nrows)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->ncols = ncols;
    cfg->nrows = nrows;
    cfg->tile_rows = 16;
    cfg->mode = WF_MODE_RAMP;
    cfg->exposure = 3;
    cfg->sca = 7;
    cfg->seed = 12345;
    cfg->compress = 1;
    wf_detector_defaults(&cfg->det);
    clock->frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin("4", &clock->ma), WF_OK);
}

static unsigned char *run_stream(const wf_readout_config *cfg, const wf_clock *clock,
                                 const wf_scene_source *scene, int threads, size_t *len)
{
    return wf_test_expose_stream(cfg, clock, scene, WF_NOISE_PHILOX, threads, len);
}

static int by_id(const void *a, const void *b)
{
    const wf_cosmic_record *p = a, *q = b;
    return p->id < q->id ? -1 : p->id > q->id;
}

static void decode(const unsigned char *buf, size_t len, decoded *d)
{
    memset(d, 0, sizeof *d);
    FILE *f = fmemopen((void *)buf, len, "rb");
    wf_packet_reader rd;
    wf_packet_reader_open(&rd, f, "test stream");
    int eof = 0, ended = 0;
    unsigned char *sat_seen = NULL;
    while (!eof) {
        wf_packet_header h;
        const void *p;
        wf_status st = wf_packet_reader_next(&rd, &h, &p, &eof);
        ck_assert_msg(st == WF_OK, "%s", wf_error_message());
        if (eof) break;
        if (h.kind == WF_PK_META) {
            const char *t = p;
            ck_assert_ptr_nonnull(strstr(t, "ncols = "));
            sscanf(strstr(t, "ncols = "), "ncols = %d", &d->ncols);
            sscanf(strstr(t, "nrows = "), "nrows = %d", &d->nrows);
            size_t n = (size_t)d->ncols * d->nrows;
            d->res = calloc(n * WF_MA_MAX_RESULTANTS, sizeof *d->res);
            d->single = calloc(n, sizeof *d->single);
            d->sat = calloc(n, 1);
            d->cr = calloc(100000, sizeof *d->cr);
            free(sat_seen);
            sat_seen = calloc((size_t)d->nrows, 1);
        } else if (h.kind == WF_PK_RESULTANTS) {
            /* a row's SATURATION comes ahead of its resultants, so that the assembler fits
             * them from the packet and never holds or reads back a tile (tools/assemble.c) */
            for (uint32_t y = 0; y < h.row_count; y++)
                ck_assert_msg(sat_seen[h.first_row + y], "RESULTANTS of row %u before its SATURATION", h.first_row + y);
            d->nres = (int)h.nplanes;
            const uint16_t *v = p;
            for (uint32_t r = 0; r < h.nplanes; r++)
                for (uint32_t y = 0; y < h.row_count; y++)
                    memcpy(d->res + ((size_t)r * d->nrows + h.first_row + y) * d->ncols,
                           v + ((size_t)r * h.row_count + y) * h.ncols, h.ncols * 2);
            d->rows_seen += (int)h.row_count;
        } else if (h.kind == WF_PK_SINGLE) {
            memcpy(d->single + (size_t)h.first_row * d->ncols, p, (size_t)h.row_count * h.ncols * 4);
            d->rows_seen += (int)h.row_count;
        } else if (h.kind == WF_PK_SATURATION) {
            memcpy(d->sat + (size_t)h.first_row * d->ncols, p, (size_t)h.row_count * h.ncols);
            memset(sat_seen + h.first_row, 1, h.row_count);
        } else if (h.kind == WF_PK_COSMIC) {
            memcpy(d->cr + d->ncr, p, h.nplanes * sizeof *d->cr);
            d->ncr += (int)h.nplanes;
        } else if (h.kind == WF_PK_END) {
            ended = 1;
        }
    }
    ck_assert(ended);
    free(sat_seen);
    qsort(d->cr, (size_t)d->ncr, sizeof *d->cr, by_id);
    wf_packet_reader_close(&rd);
    fclose(f);
}

/* run_stream, decoded */
static void run_decoded(const wf_readout_config *cfg, const wf_clock *clock,
                        const wf_scene_source *scene, int threads, decoded *d)
{
    size_t len;
    unsigned char *buf = run_stream(cfg, clock, scene, threads, &len);
    decode(buf, len, d);
    free(buf);
}

static void free_decoded(decoded *d)
{
    free(d->res);
    free(d->single);
    free(d->sat);
    free(d->cr);
}

static void assert_same(const decoded *a, const decoded *b, const char *what)
{
    size_t n = (size_t)a->ncols * a->nrows;
    ck_assert_int_eq(a->rows_seen, a->nrows);
    ck_assert_int_eq(b->rows_seen, b->nrows);
    ck_assert_msg(a->nres == b->nres, "%s: resultant count", what);
    ck_assert_msg(!memcmp(a->res, b->res, n * (size_t)a->nres * 2), "%s: resultants differ", what);
    ck_assert_msg(!memcmp(a->single, b->single, n * 4), "%s: single-frame image differs", what);
    ck_assert_msg(!memcmp(a->sat, b->sat, n), "%s: saturation maps differ", what);
    ck_assert_msg(a->ncr == b->ncr, "%s: %d vs %d cosmic rays", what, a->ncr, b->ncr);
    ck_assert_msg(!memcmp(a->cr, b->cr, (size_t)a->ncr * sizeof *a->cr), "%s: cosmic truth differs", what);
}

static wf_scene_grid test_grid(int ncols, int nrows)
{
    return (wf_scene_grid){ncols, nrows, 0.4, 3.0e5, 1.2, 24}; /* bright: some pixels saturate */
}

static void check_determinism(wf_mode mode, wf_sampling sampling)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 72, 80);
    cfg.mode = mode;
    cfg.sampling = sampling;
    cfg.exptime = 300.0;
    cfg.det.cr_rate = 2000.0; /* enough hits on a small SCA to cross tile boundaries */
    wf_scene_grid g = test_grid(cfg.ncols, cfg.nrows);
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    const int heights[] = {1, 7, 64, 80};
    decoded ref = {0};
    size_t len;
    unsigned char *buf;
    for (int i = 0; i < 4; i++) {
        cfg.tile_rows = heights[i];
        for (int threads = 1; threads <= 2; threads++) {
            if (heights[i] == 80 && threads == 2) continue;
            buf = run_stream(&cfg, &clock, &src, threads, &len);
            decoded d;
            decode(buf, len, &d);
            free(buf);
            if (i == 0 && threads == 1) {
                ref = d;
                if (mode == WF_MODE_RAMP) ck_assert_msg(ref.ncr > 10, "only %d cosmic rays", ref.ncr);
                continue;
            }
            char what[64];
            snprintf(what, sizeof what, "tile height %d, %d threads", heights[i], threads);
            assert_same(&ref, &d, what);
            free_decoded(&d);
        }
    }
    free_decoded(&ref);
}

START_TEST(determinism_ramp_per_read) { check_determinism(WF_MODE_RAMP, WF_SAMPLE_PER_READ); }
END_TEST
START_TEST(determinism_ramp_direct) { check_determinism(WF_MODE_RAMP, WF_SAMPLE_DIRECT); }
END_TEST
/* Moments' Poisson inversion has a hand-written AVX-512 variant (blocks of pixels in
 * registers, each stopped at its own largest count) beside the portable lockstep passes: both
 * give the same stream, bit for bit, with 72 columns (a partial block) and sky rates that
 * reach 0.3-9 electrons a group, where the counts are drawn by inversion. Where the CPU has no
 * AVX-512 the two runs take the same path, and the test says so. */
START_TEST(moments_portable_same_bits)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 72, 40);
    cfg.mode = WF_MODE_RAMP;
    cfg.sampling = WF_SAMPLE_MOMENTS;
    cfg.tile_rows = 16;
    wf_scene_grid g = test_grid(cfg.ncols, cfg.nrows);
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    size_t len;
    decoded d[2];
    for (int portable = 0; portable < 2; portable++) {
        cfg.portable = portable;
        unsigned char *buf = run_stream(&cfg, &clock, &src, 1, &len);
        decode(buf, len, &d[portable]);
        free(buf);
    }
    assert_same(&d[0], &d[1], "AVX-512 and portable Poisson passes");
    free_decoded(&d[0]);
    free_decoded(&d[1]);
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(__SANITIZE_ADDRESS__)
    printf("moments: AVX-512 passes %s\n", __builtin_cpu_supports("avx512f") ? "compared" : "absent (one path run twice)");
#else
    printf("moments: this build has no AVX-512 passes (one path run twice)\n");
#endif
}
END_TEST

START_TEST(determinism_ramp_moments) { check_determinism(WF_MODE_RAMP, WF_SAMPLE_MOMENTS); }
END_TEST
START_TEST(determinism_single) { check_determinism(WF_MODE_SINGLE, WF_SAMPLE_PER_READ); }
END_TEST

START_TEST(memory_fixed_by_tile_not_image)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 4088, 256);
    cfg.tile_rows = 64;
    ck_assert_int_eq(wf_ma_builtin("6", &clock.ma), WF_OK);
    size_t a, b, c;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &a), WF_OK);
    cfg.nrows = 4088;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &b), WF_OK);
    ck_assert_msg(a == b, "arena need grew with image height: %zu -> %zu", a, b);
    ck_assert_msg(b <= 64u << 20, "full-SCA readout at 64-row tiles needs %zu bytes > 64 MiB", b);
    cfg.tile_rows = 128;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &c), WF_OK);
    ck_assert_msg(c > b, "arena need must grow with tile height");
}
END_TEST

/* Resident pages of [p, p + n) by mincore, and in *pages how many it spans; -1 when that
 * cannot be told (more than 512 pages, or mincore failed). */
static int resident_pages(const unsigned char *p, size_t n, size_t *pages)
{
    size_t page = (size_t)sysconf(_SC_PAGESIZE);
    unsigned char vec[512];
    *pages = (n + page - 1) / page;
    if (*pages > sizeof vec || mincore((void *)(uintptr_t)p, n, vec) != 0) return -1;
    int resident = 0;
    for (size_t i = 0; i < *pages; i++) resident += vec[i] & 1;
    return resident;
}

/* The kernel's count of huge-page faults it served with small pages (none to be had). */
static long thp_fallbacks(void)
{
    FILE *f = fopen("/proc/vmstat", "r");
    char key[64];
    long v, n = 0;
    while (f && fscanf(f, "%63s %ld", key, &v) == 2)
        if (!strcmp(key, "thp_fault_fallback")) n = v;
    if (f) fclose(f);
    return n;
}

/* Host memory for arenas: 2 MiB aligned, the whole rounded size usable, NULL when it cannot
 * be had; where the kernel offers transparent huge pages, filling 8 MiB takes a handful of
 * page faults rather than 2048 (the reason it exists: faults are slow on a virtual machine). */
START_TEST(arena_host_memory)
{
    const size_t mib = (size_t)1 << 20;
    unsigned char *p = wf_arena_host_alloc(8 * mib - 100);
    ck_assert_ptr_nonnull(p);
    ck_assert_uint_eq((uintptr_t)p % (2 * mib), 0);
    struct rusage a, b;
    long fallback0 = thp_fallbacks();
    getrusage(RUSAGE_SELF, &a);
    memset(p, 0x5a, 8 * mib); /* rounded up to whole huge pages: the tail is ours too */
    getrusage(RUSAGE_SELF, &b);
    long fallback = thp_fallbacks() - fallback0;
    ck_assert_uint_eq(p[8 * mib - 1], 0x5a);
    free(p);
    /* a thin tail (100 KiB past 4 MiB) stays ordinary pages: one byte of it makes one page
     * resident, not a whole huge page */
    const size_t thin = 4 * mib + 100 * 1024;
    unsigned char *q = wf_arena_host_alloc(thin);
    ck_assert_ptr_nonnull(q);
    memset(q, 0x5a, 4 * mib);
    q[4 * mib] = 1;
    size_t tail_pages;
    int resident = resident_pages(q + 4 * mib, thin - 4 * mib, &tail_pages);
    free(q);
    ck_assert_ptr_null(wf_arena_host_alloc(SIZE_MAX - 4096));
    ck_assert_ptr_null(wf_arena_host_alloc(0));
    char thp[128] = "";
    FILE *tf = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
    int on = tf && fgets(thp, sizeof thp, tf) && !strstr(thp, "[never]");
    if (tf) fclose(tf);
    if (!on) WF_SKIP("transparent huge pages are off on this kernel: fault count not checked");
    if (fallback > 0) WF_SKIP("the kernel had no huge page free (thp_fault_fallback): fault count not checked");
    long faults = b.ru_minflt - a.ru_minflt;
    ck_assert_msg(faults < 1024, "8 MiB filled with %ld page faults: no huge pages", faults);
    if (strstr(thp, "[madvise]")) /* with THP always, every page may be huge */
        ck_assert_msg(resident == 1, "one byte of a 100 KiB tail made %d of its %zu pages resident", resident,
                      tail_pages);
}
END_TEST

/* Host buffers grown by wf_arena_host_realloc keep their contents; from 1 MiB they are
 * aligned to a huge page and on huge pages, but for a tail beyond the last whole one that
 * fills less than half a huge page: that stays ordinary pages, so that touching it does not
 * make 2 MiB resident. */
/* Faults that filling `bytes` of fresh memory costs beyond its own pages: AddressSanitizer's
 * shadow (one byte per eight, in 4 KiB pages) faults in as well. */
static long shadow_faults(size_t bytes)
{
#if defined(__SANITIZE_ADDRESS__)
    return (long)(bytes / 8 / 4096) + 1;
#else
    (void)bytes;
    return 0;
#endif
}

static long touch_faults(unsigned char *p, size_t n)
{
    struct rusage a, b;
    getrusage(RUSAGE_SELF, &a);
    memset(p, 0x5a, n);
    getrusage(RUSAGE_SELF, &b);
    return b.ru_minflt - a.ru_minflt;
}

START_TEST(arena_host_realloc_grows)
{
    const size_t mib = (size_t)1 << 20, kib = 1024;
    const size_t thin = 4 * mib + 100 * kib, thick = 4 * mib + mib; /* tails below / at half a huge page */
    long fallback0 = thp_fallbacks();
    /* first, while no large block has been freed: glibc then serves it fresh from the kernel */
    unsigned char *r = wf_arena_host_realloc(NULL, 0, thick);
    ck_assert_ptr_nonnull(r);
    long f_thick = touch_faults(r, thick);
    ck_assert_uint_eq(r[thick - 1], 0x5a);
    unsigned char *p = wf_arena_host_realloc(NULL, 0, 1000);
    ck_assert_ptr_nonnull(p);
    for (int i = 0; i < 1000; i++) p[i] = (unsigned char)(i * 7);
    p = wf_arena_host_realloc(p, 1000, 3000);
    ck_assert_ptr_nonnull(p);
    for (int i = 0; i < 1000; i++) ck_assert_uint_eq(p[i], (unsigned char)(i * 7));
    unsigned char *q = wf_arena_host_realloc(p, 1000, thin);
    ck_assert_ptr_nonnull(q);
    ck_assert_uint_eq((uintptr_t)q % (2 * mib), 0);
    for (int i = 0; i < 1000; i++) ck_assert_uint_eq(q[i], (unsigned char)(i * 7));
    /* out of memory: NULL, and the buffer is still the caller's */
    ck_assert_ptr_null(wf_arena_host_realloc(q, thin, SIZE_MAX - 4096));
    ck_assert_uint_eq(q[999], (unsigned char)(999 * 7));
    char thp[128] = "";
    FILE *tf = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
    int madvise_only = tf && fgets(thp, sizeof thp, tf) && strstr(thp, "[madvise]");
    if (tf) fclose(tf);
    long f_whole = touch_faults(q, 4 * mib); /* the two whole huge pages */
    q[4 * mib] = 1;                          /* and one byte of the thin tail */
    size_t tail_pages;
    int resident = resident_pages(q + 4 * mib, thin - 4 * mib, &tail_pages);
    free(q);
    free(r);
    long fallback = thp_fallbacks() - fallback0;
    if (!madvise_only) WF_SKIP("transparent huge pages are not in madvise mode here: page use not checked");
    if (fallback > 0) WF_SKIP("the kernel had no huge page free (thp_fault_fallback): page use not checked");
    ck_assert_msg(f_whole < 64 + shadow_faults(4 * mib), "4 MiB of whole huge pages filled with %ld page faults", f_whole);
    ck_assert_msg(resident == 1, "one byte of a 100 KiB tail made %d of its %zu pages resident", resident, tail_pages);
    ck_assert_msg(f_thick < 64 + shadow_faults(thick), "5 MiB (a 1 MiB tail) filled with %ld page faults", f_thick);
}
END_TEST

/* An arena filled only in part: its dense start on huge pages, the rest ordinary pages that
 * stay out of resident memory until touched. */
START_TEST(arena_host_alloc_dense_part)
{
    const size_t mib = (size_t)1 << 20, size = 8 * mib, dense = 3 * mib;
    long fallback0 = thp_fallbacks();
    unsigned char *p = wf_arena_host_alloc_dense(size, dense);
    ck_assert_ptr_nonnull(p);
    ck_assert_uint_eq((uintptr_t)p % (2 * mib), 0);
    long f_dense = touch_faults(p, dense);
    p[6 * mib] = 1; /* one byte past the dense part's huge pages */
    long page = sysconf(_SC_PAGESIZE);
    size_t n = 2 * mib / (size_t)page;
    unsigned char vec[1024];
    int resident = -1;
    if (n <= sizeof vec && mincore(p + 6 * mib, 2 * mib, vec) == 0) {
        resident = 0;
        for (size_t i = 0; i < n; i++) resident += vec[i] & 1;
    }
    ck_assert_uint_eq(p[dense - 1], 0x5a);
    free(p);
    ck_assert_ptr_null(wf_arena_host_alloc_dense(SIZE_MAX - 4096, 0));
    char thp[128] = "";
    FILE *tf = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
    int madvise_only = tf && fgets(thp, sizeof thp, tf) && strstr(thp, "[madvise]");
    if (tf) fclose(tf);
    if (!madvise_only) WF_SKIP("transparent huge pages are not in madvise mode here: page use not checked");
    if (thp_fallbacks() > fallback0) WF_SKIP("the kernel had no huge page free (thp_fault_fallback): page use not checked");
    ck_assert_msg(f_dense < 64 + shadow_faults(dense), "3 MiB of the dense part filled with %ld page faults", f_dense);
    ck_assert_msg(resident == 1, "one byte past the dense part made %d of %zu pages resident", resident, n);
}
END_TEST

START_TEST(arena_refuses_past_budget)
{
    static unsigned char block[4096];
    wf_arena arena;
    wf_arena_init(&arena, block, sizeof block, "test arena");
    void *p;
    ck_assert_int_eq(wf_arena_alloc(&arena, 1000, "first", &p), WF_OK);
    ck_assert_int_eq(wf_arena_alloc(&arena, 4000, "too big", &p), WF_ERR_NOMEM);
    ck_assert_ptr_null(p);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "too big"));
    size_t mark = wf_arena_mark(&arena);
    ck_assert_int_eq(wf_arena_alloc(&arena, 1000, "second", &p), WF_OK);
    wf_arena_release(&arena, mark);
    ck_assert_int_eq(wf_arena_mark(&arena), mark);

    /* a readout given less than it asked for fails cleanly */
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 64, 64);
    size_t need;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_OK);
    void *mem = malloc(need);
    wf_arena_init(&arena, mem, need / 2, "half arena");
    wf_scene_grid g = test_grid(64, 64);
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    wf_noise noise = {WF_NOISE_PHILOX, 1, 1, 1};
    wf_link_memory lm;
    wf_link link;
    wf_link_memory_open(&lm, &link);
    wf_readout *ro;
    ck_assert_int_eq(wf_readout_create(&cfg, &clock, &src, &noise, &link, &arena, &ro), WF_ERR_NOMEM);
    /* and with its full budget it runs and stays within it */
    wf_arena_init(&arena, mem, need, "full arena");
    ck_assert_int_eq(wf_readout_create(&cfg, &clock, &src, &noise, &link, &arena, &ro), WF_OK);
    for (int t = 0; t < wf_readout_tile_count(ro); t++) ck_assert_int_eq(wf_readout_run_tile(ro, t), WF_OK);
    ck_assert(arena.high_water <= need);
    wf_readout_destroy(ro);
    wf_link_memory_close(&lm);
    free(mem);
}
END_TEST

/* With every noise and non-linear effect off, resultant r of every pixel is rate x tbar_r,
 * so the image sums to the scene's closed-form total. */
START_TEST(noiseless_flux_conserved)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 96, 96);
    wf_detector *d = &cfg.det;
    memset(&d->on, 0, sizeof d->on);
    wf_scene_grid g = {96, 96, 0.4, 2000.0, 1.5, 32};
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    const wf_sampling samplings[] = {WF_SAMPLE_PER_READ, WF_SAMPLE_DIRECT, WF_SAMPLE_MOMENTS};
    for (int s = 0; s < 3; s++) {
        cfg.sampling = samplings[s];
        decoded dd;
        run_decoded(&cfg, &clock, &src, 1, &dd);
        double total = wf_scene_grid_total(&g);
        for (int r = 0; r < dd.nres; r++) {
            double sum = 0.0;
            for (size_t i = 0; i < (size_t)96 * 96; i++) sum += dd.res[(size_t)r * 96 * 96 + i];
            double expect = total * wf_clock_resultant_time(&clock, r) + d->bias_adu * 96 * 96;
            /* each pixel is rounded to an integer ADU: at most 0.5 each */
            ck_assert_msg(fabs(sum - expect) <= 0.5 * 96 * 96 + 1e-4 * expect,
                          "resultant %d: sum %.1f, expected %.1f", r, sum, expect);
        }
        free_decoded(&dd);
    }
}
END_TEST

/* Direct-resultant sampling draws the same distribution as read-by-read sampling for a
 * linear pixel: per-resultant means and variances over many pixels agree within 4 sigma. */
START_TEST(direct_matches_per_read)
{
    /* 3 e-/s: ~9 e- a read, by inversion; 40 e-/s: ~120 e- a read, PTRS from the pixel's own
     * stream in per-read sampling */
    const double rates[] = {3.0, 40.0};
    for (int k = 0; k < 2; k++) {
        wf_readout_config cfg;
        wf_clock clock;
        small_config(&cfg, &clock, 128, 128);
        ck_assert_int_eq(wf_ma_builtin("6", &clock.ma), WF_OK);
        wf_detector *d = &cfg.det;
        memset(&d->on, 0, sizeof d->on);
        d->on.photon_noise = 1;
        wf_scene_grid g = {128, 128, rates[k], 0.0, 1.0, 64}; /* flat: photon noise only */
        wf_scene_source src;
        wf_scene_grid_source(&g, &src);
        decoded dd[2];
        for (int s = 0; s < 2; s++) {
            cfg.sampling = s ? WF_SAMPLE_DIRECT : WF_SAMPLE_PER_READ;
            run_decoded(&cfg, &clock, &src, 1, &dd[s]);
        }
        size_t n = 128 * 128;
        for (int r = 0; r < dd[0].nres; r++) {
            double m[2], v[2];
            for (int s = 0; s < 2; s++) {
                double a = 0, b = 0;
                for (size_t i = 0; i < n; i++) {
                    double x = dd[s].res[(size_t)r * n + i];
                    a += x;
                    b += x * x;
                }
                m[s] = a / n;
                v[s] = b / n - m[s] * m[s];
            }
            double tb = wf_clock_resultant_time(&clock, r);
            ck_assert_msg(fabs(m[0] - m[1]) < 4.0 * sqrt((v[0] + v[1]) / n),
                          "%g e-/s, resultant %d: means %.4f vs %.4f", rates[k], r, m[0], m[1]);
            double expect = rates[k] * tb + cfg.det.bias_adu;
            ck_assert_msg(fabs(m[0] - expect) < 4.0 * sqrt(v[0] / n) + 0.5, "%g e-/s, resultant %d mean %.3f vs %.3f",
                          rates[k], r, m[0], expect);
            /* variance of a sample variance ~ 2 v^2 / n (near-Gaussian counts), plus rounding */
            double tol = 4.0 * sqrt(2.0 / n) * (v[0] + v[1]) / 2 + 1.0 / 6.0;
            ck_assert_msg(fabs(v[0] - v[1]) < tol, "%g e-/s, resultant %d: variances %.4f vs %.4f", rates[k], r, v[0],
                          v[1]);
        }
        free_decoded(&dd[0]);
        free_decoded(&dd[1]);
    }
}
END_TEST

/* Rates chosen per column so that a read's mean runs from 0 through the tiny to just below
 * 10: the per-read Poisson draws of every count the row-at-a-time inversion finds itself and
 * of those it leaves to the one-pixel path (counts above 6, a sum that stops growing). */
static const double exact_means[] = {0.0, 1e-9, 1e-4, 0.05, 0.4, 1.1, 2.0, 3.3, 5.0, 7.5, 9.2, 9.999};
enum { EXACT_NM = sizeof exact_means / sizeof exact_means[0] };

static wf_status exact_fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    const double ft = *(const double *)ctx;
    for (int y = y0; y < y1; y++)
        for (int x = 0; x < ncols; x++)
            rate[(size_t)(y - y0) * ncols + x] = (float)(exact_means[(x + 5 * y) % EXACT_NM] / ft);
    return WF_OK;
}

/* Poisson by inversion, as SPEC's per-read sampling defines it: the smallest k whose
 * cumulative probability reaches u = (w + 0.5) / 2^32, the terms p_k = p_(k-1) m / k summed
 * in order (at most 200; a term that no longer changes the sum ends it). */
static double inversion(uint32_t w, double m)
{
    if (!(m > 0.0)) return 0.0;
    double u = ((double)w + 0.5) * (1.0 / 4294967296.0), e = exp(-m);
    double p1 = e * m, p2 = p1 * m * 0.5, f0 = e, f1 = f0 + p1, f2 = f1 + p2;
    if (u <= f2) return (double)((u > f0) + (u > f1));
    double p = p2, cdf = f2, k = 2.0;
    while (u > cdf && k < 200.0) {
        k += 1.0;
        p *= m / k;
        if (cdf + p == cdf) break;
        cdf += p;
    }
    return k;
}

/* Photon noise alone, one read per resultant, unit gain, no bias: each resultant is the
 * charge collected so far, and must be the sum of the inversion draws from each pixel's
 * words (word 1 of block 0 of its pair's stream at each read, word 3 in the row's second
 * half), every pixel and read exactly. */
START_TEST(per_read_counts_exact)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 67, 37); /* odd sizes: the rows' vector tails, a short tile */
    const int counts[] = {1, 1, 1, 1, 1, 1, 1, 1};
    ck_assert_int_eq(wf_ma_from_counts("ones", counts, 8, &clock.ma), WF_OK);
    wf_detector *d = &cfg.det;
    memset(&d->on, 0, sizeof d->on);
    d->on.photon_noise = 1;
    d->gain = 1.0;
    d->bias_adu = 0.0;
    double ft = clock.frame_time;
    wf_scene_source src = {&ft, exact_fill, NULL, NULL};
    decoded dd;
    run_decoded(&cfg, &clock, &src, 1, &dd);
    ck_assert_int_eq(dd.nres, 8);
    wf_noise noise = {WF_NOISE_PHILOX, cfg.seed, cfg.exposure, cfg.sca};
    long above6 = 0, zero = 0;
    const int h = (cfg.ncols + 1) / 2; /* a block serves pixels x and x + h of a row */
    for (int y = 0; y < cfg.nrows; y++)
        for (int x = 0; x < cfg.ncols; x++) {
            uint32_t w[4];
            double m = (double)(float)(exact_means[(x + 5 * y) % EXACT_NM] / ft) * ft, q = 0.0;
            for (int r = 0; r < 8; r++) {
                wf_noise_block_row(&noise, (uint32_t)(y * h + (x < h ? x : x - h)), 1, (uint32_t)r,
                                   WF_PURPOSE_PHOTON_PAIR, 0, &w[0], &w[1], &w[2], &w[3]);
                double k = inversion(w[x < h ? 1 : 3], m);
                above6 += k > 6.0;
                zero += k == 0.0;
                q += k;
                uint16_t got = dd.res[((size_t)r * cfg.nrows + y) * cfg.ncols + x];
                ck_assert_msg(got == (uint16_t)q, "pixel (%d, %d), read %d, mean %g: %u, want %g", x, y, r,
                              m, got, q);
            }
        }
    ck_assert_msg(above6 > 20 && zero > 100, "counts above 6: %ld, zeros: %ld", above6, zero);
    free_decoded(&dd);
}
END_TEST

/* A pixel that saturates within the ramp: resultants never decrease, never exceed the
 * saturation level, and the saturation map names the first resultant whose reads reached it
 * (here the 16-bit ADC, at 65535 ADU, comes before the full well). */
START_TEST(saturation_defined)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 16, 16);
    cfg.det.on.cosmic_rays = 0;
    cfg.det.on.ipc = 0; /* IPC would move charge between the flat pixels' neighbours only */
    wf_scene_grid g = {16, 16, 500.0, 0.0, 1.0, 64}; /* flat 500 e-/s: the ADC clips after ~134 s */
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    decoded dd;
    run_decoded(&cfg, &clock, &src, 1, &dd);
    double rate = wf_det_reciprocity_rate(500.0, cfg.det.recip_alpha, cfg.det.recip_f0) + cfg.det.dark_current;
    double sat_adu = wf_det_saturation_adu(&cfg.det);
    /* charge at which the measured signal reaches the saturation level: invert q + beta q^2 */
    double beta = cfg.det.nl_beta, level = (sat_adu - cfg.det.bias_adu) * cfg.det.gain;
    double q_sat = (-1.0 + sqrt(1.0 + 4.0 * beta * level)) / (2.0 * beta);
    double tol = 5.0 * sqrt(q_sat) + 5.0 * cfg.det.read_noise_e;
    size_t n = 16 * 16;
    int saturated = 0;
    for (size_t i = 0; i < n; i++) {
        for (int r = 0; r < dd.nres; r++) {
            ck_assert(dd.res[(size_t)r * n + i] <= sat_adu + 0.5);
            if (r) ck_assert_msg(dd.res[(size_t)r * n + i] + 40 >= dd.res[(size_t)(r - 1) * n + i], "decreasing ramp");
        }
        if (dd.sat[i] != 255) {
            saturated++;
            /* first read whose expected charge passes the full well, within Poisson spread */
            int r = dd.sat[i];
            const wf_ma_table *ma = &clock.ma;
            double t_last = wf_clock_read_time(&clock, ma->read[ma->first[r + 1] - 1]);
            double t_prev = r ? wf_clock_read_time(&clock, ma->read[ma->first[r] - 1]) : 0.0;
            ck_assert_msg(rate * t_last >= q_sat - tol,
                          "flagged at resultant %d before the signal could saturate", r);
            ck_assert_msg(rate * t_prev <= q_sat + tol, "flag at resultant %d too late", r);
        }
    }
    ck_assert_int_eq(saturated, (int)n);
    free_decoded(&dd);
}
END_TEST

/* Single-frame order without noise: ADU = round(IPC(NL(recip(r t) + dark t)) / gain), which
 * here is checked on a flat interior pixel, where IPC sums to one. */
START_TEST(single_frame_closed_form)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 20, 20);
    cfg.mode = WF_MODE_SINGLE;
    cfg.exptime = 139.8;
    cfg.det.on.photon_noise = cfg.det.on.read_noise = 0;
    wf_scene_grid g = {20, 20, 123.0, 0.0, 1.0, 64};
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    decoded dd;
    run_decoded(&cfg, &clock, &src, 1, &dd);
    double q = wf_det_reciprocity(123.0 * 139.8, 139.8, 0.0065, 1.0) + 0.015 * 139.8;
    double expect = nearbyint(wf_det_nonlinearity(q, -6e-7) + cfg.det.bias_adu);
    ck_assert_msg(fabs(dd.single[10 * 20 + 10] - expect) < 1e-9, "single frame %.3f vs %.3f",
                  dd.single[10 * 20 + 10], expect);
    /* a corner keeps only the kernel weights that fall inside (zero padding) */
    const double (*k)[3] = cfg.det.ipc;
    double corner = k[1][1] + k[1][2] + k[2][1] + k[2][2];
    ck_assert_msg(fabs(dd.single[0] - nearbyint(wf_det_nonlinearity(q, -6e-7) * corner + cfg.det.bias_adu)) < 1e-9,
                  "corner pixel %.3f", dd.single[0]);
    free_decoded(&dd);
}
END_TEST

/* The number of cosmic-ray hits matches rate x area x time (Poisson, 5 sigma). */
START_TEST(cosmic_ray_count)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 256, 256);
    ck_assert_int_eq(wf_ma_builtin("6", &clock.ma), WF_OK);
    cfg.det.cr_rate = 100.0;
    wf_scene_grid g = {256, 256, 0.4, 0.0, 1.0, 64};
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    decoded dd;
    run_decoded(&cfg, &clock, &src, 1, &dd);
    double expect = wf_cosmic_expected_hits(&cfg.det, 256, 256, wf_clock_exposure_time(&clock));
    ck_assert_msg(fabs(dd.ncr - expect) < 5.0 * sqrt(expect), "%d hits, expected %.1f", dd.ncr, expect);
    for (int i = 1; i < dd.ncr; i++) ck_assert(dd.cr[i].id != dd.cr[i - 1].id);
    for (int i = 0; i < dd.ncr; i++) {
        ck_assert(dd.cr[i].read < 93);
        ck_assert(dd.cr[i].electrons >= 0.0f);
    }
    free_decoded(&dd);
}
END_TEST

/* A tile whose cosmic-ray truth is larger than its resultants (a high rate on a small
 * tile): the packet buffer holds the COSMIC packet too, and the hits all arrive. */
START_TEST(cosmic_truth_larger_than_tile)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 16, 16);
    cfg.det.cr_rate = 2e5;
    double expect = wf_cosmic_expected_hits(&cfg.det, 16, 16, wf_clock_exposure_time(&clock));
    size_t payload = (size_t)16 * 16 * 2 * (size_t)clock.ma.nresultants;
    ck_assert_msg(expect * sizeof(wf_cosmic_record) > WF_READOUT_META_MAX && expect < 90000,
                  "%.0f hits (%zu bytes of resultants) do not test it", expect, payload);
    wf_scene_grid g = {16, 16, 0.4, 0.0, 1.0, 64};
    wf_scene_source src;
    wf_scene_grid_source(&g, &src);
    decoded dd;
    run_decoded(&cfg, &clock, &src, 1, &dd);
    ck_assert_msg(fabs(dd.ncr - expect) < 5.0 * sqrt(expect), "%d hits, expected %.1f", dd.ncr, expect);
    free_decoded(&dd);
}
END_TEST

/* One readout instance in an arena of exactly its need, on a grid scene and a memory link
 * (lm holds what it sent). */
typedef struct instance {
    size_t need;
    void *mem;
    wf_arena arena;
    wf_scene_grid g;
    wf_scene_source src;
    wf_noise noise;
    wf_link_memory lm;
    wf_link link;
    wf_readout *ro;
} instance;

static void instance_open(instance *in, const wf_readout_config *cfg, const wf_clock *clock)
{
    memset(in, 0, sizeof *in);
    ck_assert_msg(wf_readout_arena_need(cfg, clock, &in->need) == WF_OK, "%s", wf_error_message());
    in->mem = malloc(in->need);
    wf_arena_init(&in->arena, in->mem, in->need, "instance");
    in->g = test_grid(cfg->ncols, cfg->nrows);
    wf_scene_grid_source(&in->g, &in->src);
    in->noise = (wf_noise){WF_NOISE_PHILOX, 1, 1, 1};
    wf_link_memory_open(&in->lm, &in->link);
    ck_assert_msg(wf_readout_create(cfg, clock, &in->src, &in->noise, &in->link, &in->arena, &in->ro) == WF_OK,
                  "%s", wf_error_message());
}

static void instance_close(instance *in)
{
    ck_assert(in->arena.high_water <= in->need);
    wf_readout_destroy(in->ro);
    wf_link_memory_close(&in->lm);
    free(in->mem);
}

/* Checked size arithmetic (hal/size.h): a product or sum that would wrap saturates, and
 * stays saturated; the arena's alignment cost and typed allocation refuse it. */
START_TEST(size_arithmetic_saturates)
{
    ck_assert_uint_eq(wf_size_mul(3, 5), 15);
    ck_assert_uint_eq(wf_size_mul(SIZE_MAX / 2 + 1, 2), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_mul(WF_SIZE_OVERFLOW, 0), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_mul3((size_t)1 << 30, (size_t)1 << 30, (size_t)1 << 30), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_add(SIZE_MAX - 10, 10), SIZE_MAX); /* exactly the top: taken as overflow too */
    ck_assert_uint_eq(wf_size_add(SIZE_MAX - 10, 11), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_add(WF_SIZE_OVERFLOW, 0), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_from_double(5.7, 100), 5);
    ck_assert_uint_eq(wf_size_from_double(100.0, 100), 100);
    ck_assert_uint_eq(wf_size_from_double(100.5, 100), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_from_double(1e300, (size_t)INT_MAX), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_from_double(-1.0, 100), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_size_from_double(NAN, 100), WF_SIZE_OVERFLOW);
    ck_assert_uint_eq(wf_arena_cost(65), 128);
    ck_assert_uint_eq(wf_arena_cost(SIZE_MAX - 10), WF_SIZE_OVERFLOW); /* once wrapped to 0 */
    static unsigned char block[4096];
    wf_arena arena;
    wf_arena_init(&arena, block, sizeof block, "test arena");
    void *p;
    ck_assert_int_eq(wf_arena_calloc(&arena, SIZE_MAX / 2, 3, "huge", &p), WF_ERR_NOMEM);
    ck_assert_int_eq(wf_arena_alloc(&arena, SIZE_MAX - 10, "huge", &p), WF_ERR_NOMEM);
    ck_assert_ptr_null(p);
}
END_TEST

/* Frame and exposure times have physical bounds (hal/clock.h, docs/CONFIG.md): just inside
 * they are sized, just outside (and absurd values such as 1e300, which once came out as a
 * negative byte count) they are refused with the reason, never sized; an MA table may not
 * name reads past WF_MA_MAX_READS (the readout indexes a table of that length by read), and
 * cosmic rays beyond what a tile's buffers count are refused, not wrapped. */
START_TEST(time_and_size_limits)
{
    wf_readout_config cfg;
    wf_clock clock;
    size_t need;
    small_config(&cfg, &clock, 64, 64);
    clock.frame_time = WF_FRAME_TIME_MAX;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_OK);
    const double bad_frame[] = {nextafter(WF_FRAME_TIME_MAX, INFINITY), 1e300, INFINITY, NAN, 0.0, -1.0};
    for (int i = 0; i < 6; i++) {
        clock.frame_time = bad_frame[i];
        ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_ERR_RANGE);
        ck_assert_ptr_nonnull(strstr(wf_error_message(), "frame time"));
    }
    /* one resultant of read 2048: the longest table, a day at 42.1875 s a frame */
    const int longest[1] = {WF_MA_MAX_READS};
    ck_assert_int_eq(wf_ma_from_counts("longest", longest, 1, &clock.ma), WF_OK);
    clock.frame_time = WF_EXPOSURE_TIME_MAX / WF_MA_MAX_READS;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_OK);
    clock.frame_time = nextafter(WF_EXPOSURE_TIME_MAX / WF_MA_MAX_READS, INFINITY);
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "exposure time"));
    clock.frame_time = WF_FRAME_TIME_DEFAULT;
    clock.ma.read[clock.ma.nreads - 1] = WF_MA_MAX_READS; /* a read past the table */
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_ERR_RANGE);
    ck_assert_int_eq(wf_ma_builtin("4", &clock.ma), WF_OK);
    /* single frame */
    cfg.mode = WF_MODE_SINGLE;
    cfg.exptime = WF_EXPOSURE_TIME_MAX;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_OK);
    const double bad_exp[] = {nextafter(WF_EXPOSURE_TIME_MAX, INFINITY), 1e300, NAN, 0.0};
    for (int i = 0; i < 4; i++) {
        cfg.exptime = bad_exp[i];
        ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_ERR_RANGE);
    }
    /* cosmic rays: a rate no tile can count is refused with its reason */
    cfg.mode = WF_MODE_RAMP;
    cfg.det.cr_rate = 1e30;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &need), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "cosmic rays"));
    /* the longest exposure at the default rate is sized, and its readout is made in it */
    cfg.det.cr_rate = 5.0;
    ck_assert_int_eq(wf_ma_from_counts("longest", longest, 1, &clock.ma), WF_OK);
    clock.frame_time = WF_EXPOSURE_TIME_MAX / WF_MA_MAX_READS;
    instance in;
    instance_open(&in, &cfg, &clock);
    ck_assert_int_eq(wf_readout_send_meta(in.ro, NULL), WF_OK);
    instance_close(&in);
}
END_TEST

/* The META text does not depend on the detector's size: a 1 x 1 detector sends the same
 * lines as a large one, with host lines up to half of WF_READOUT_META_MAX; more is refused
 * with its length, and the text's room is given back to the arena either way. */
START_TEST(meta_fits_any_detector)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 1, 1);
    cfg.tile_rows = 1;
    cfg.compress = 0; /* the uncompressed text must fit one packet too */
    instance in;
    instance_open(&in, &cfg, &clock);
    size_t mark = wf_arena_mark(&in.arena), half = WF_READOUT_META_MAX / 2;
    char *extra = malloc(WF_READOUT_META_MAX + 1);
    for (size_t i = 0; i < half; i++) extra[i] = i % 64 == 63 ? '\n' : 'x';
    extra[half] = '\0';
    ck_assert_int_eq(wf_readout_send_meta(in.ro, extra), WF_OK);
    ck_assert_uint_eq(wf_arena_mark(&in.arena), mark);
    /* the packet carries every byte: the fixed lines and the extra ones */
    wf_packet_header h;
    ck_assert_int_eq(wf_packet_header_read(in.lm.data, &h), WF_OK);
    ck_assert_uint_eq(h.kind, WF_PK_META);
    ck_assert_uint_gt(h.raw_len, half);
    ck_assert_uint_eq(in.lm.len, WF_PACKET_HEADER_SIZE + h.raw_len); /* not deflated: the text as it is */
    ck_assert(!memcmp(in.lm.data + in.lm.len - half, extra, half));
    memset(extra, 'x', WF_READOUT_META_MAX);
    extra[WF_READOUT_META_MAX] = '\0';
    ck_assert_int_eq(wf_readout_send_meta(in.ro, extra), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "META text longer"));
    ck_assert_uint_eq(wf_arena_mark(&in.arena), mark);
    free(extra);
    instance_close(&in);
}
END_TEST

START_TEST(replay_equals_source)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 40, 33);
    wf_scene_grid g = test_grid(40, 33);
    wf_scene_source src, rep;
    wf_scene_grid_source(&g, &src);
    char path[4200];
    snprintf(path, sizeof path, "%s/rates.bin", wf_test_tmpdir());
    float scratch[40 * 5];
    ck_assert_int_eq(wf_scene_record(&src, 40, 33, 5, scratch, path), WF_OK);
    wf_scene_replay rp;
    ck_assert_int_eq(wf_scene_replay_open(&rp, path, &rep), WF_OK);
    size_t la, lb;
    unsigned char *a = run_stream(&cfg, &clock, &src, 1, &la);
    unsigned char *b = run_stream(&cfg, &clock, &rep, 1, &lb);
    ck_assert_msg(la == lb && !memcmp(a, b, la), "replayed stream differs from the live scene");
    free(a);
    free(b);
    wf_scene_replay_close(&rp);
    ck_assert_int_eq(wf_scene_replay_open(&rp, "/nonexistent/rates.bin", &rep), WF_ERR_IO);
}
END_TEST

/* A source whose rate changes linearly in time: rate r0 at the mid-time, slope g. */
typedef struct linear_source {
    double r0, g;
} linear_source;

static wf_status linear_rate(void *ctx, int y0, int y1, int ncols, float *rate)
{
    const linear_source *l = ctx;
    for (size_t i = 0; i < (size_t)(y1 - y0) * ncols; i++) rate[i] = (float)l->r0;
    return WF_OK;
}

static wf_status linear_slope(void *ctx, int y0, int y1, int ncols, float *slope, int *any)
{
    const linear_source *l = ctx;
    for (size_t i = 0; i < (size_t)(y1 - y0) * ncols; i++) slope[i] = (float)l->g;
    *any = l->g != 0.0;
    return WF_OK;
}

/* Up the ramp with every effect but the ADC off, a rate r0 + g (t - T/2) gives the charge
 * Q(t) = r0 t + g (t^2/2 - t T/2) at read time t: each resultant is the mean of Q over its
 * reads plus the bias, rounded. Per-read and direct sampling both, and a zero slope is the
 * constant source to the bit. */
static void check_linear(wf_sampling sampling)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 24, 20);
    cfg.sampling = sampling;
    cfg.time_variable = 1;
    memset(&cfg.det.on, 0, sizeof cfg.det.on); /* the ADC still rounds the resultants */
    const double r0 = 50.0, g = 0.02; /* -49 e- at mid-time against a constant rate */
    linear_source ls = {r0, g};
    wf_scene_source src = {&ls, linear_rate, NULL, linear_slope};
    decoded d;
    run_decoded(&cfg, &clock, &src, 1, &d);
    double T = wf_clock_exposure_time(&clock), tm = 0.5 * T;
    double maxdev = 0, maxeffect = 0;
    for (int r = 0; r < clock.ma.nresultants; r++) {
        double sum = 0, flat = 0;
        int n = clock.ma.first[r + 1] - clock.ma.first[r];
        for (int j = clock.ma.first[r]; j < clock.ma.first[r + 1]; j++) {
            double t = wf_clock_read_time(&clock, clock.ma.read[j]);
            sum += r0 * t + g * (t * t / 2 - t * tm);
            flat += r0 * t;
        }
        double want = sum / n / cfg.det.gain + cfg.det.bias_adu;
        if (fabs((sum - flat) / n) > maxeffect) maxeffect = fabs((sum - flat) / n);
        for (int i = 0; i < d.ncols * d.nrows; i++) {
            double got = d.res[(size_t)r * d.ncols * d.nrows + i];
            if (fabs(got - want) > maxdev) maxdev = fabs(got - want);
        }
    }
    ck_assert_msg(maxeffect > 40, "the slope should move some resultant by ~49 e- (%.1f)", maxeffect);
    ck_assert_msg(maxdev <= 0.5 + 1e-6, "resultants off the closed form by %.3f ADU", maxdev);
    free_decoded(&d);
    /* slope 0: the same bytes as a constant source without fill_slope */
    ls.g = 0.0;
    run_decoded(&cfg, &clock, &src, 1, &d);
    wf_scene_source flat_src = {&ls, linear_rate, NULL, NULL};
    cfg.time_variable = 0;
    decoded e;
    run_decoded(&cfg, &clock, &flat_src, 1, &e);
    assert_same(&d, &e, "zero slope");
    free_decoded(&d);
    free_decoded(&e);
}

START_TEST(linear_rate_per_read) { check_linear(WF_SAMPLE_PER_READ); }
END_TEST
START_TEST(linear_rate_direct) { check_linear(WF_SAMPLE_DIRECT); }
END_TEST

/* A flat field of `rate` e-/s with only the effects in `on` (gain 1 ADU/e-), decoded. */
static void flat_run(wf_sampling sampling, double rate, int nl, double beta, int ncols, int nrows,
                     wf_readout_config *cfg, wf_clock *clock, decoded *d)
{
    small_config(cfg, clock, ncols, nrows);
    cfg->tile_rows = 32;
    cfg->sampling = sampling;
    memset(&cfg->det.on, 0, sizeof cfg->det.on);
    cfg->det.on.photon_noise = cfg->det.on.read_noise = 1;
    cfg->det.on.nonlinearity = nl;
    cfg->det.nl_beta = beta;
    ck_assert_double_eq(cfg->det.gain, 1.0);
    static linear_source ls;
    ls = (linear_source){rate, 0.0};
    wf_scene_source src = {&ls, linear_rate, NULL, NULL};
    run_decoded(cfg, clock, &src, 1, d);
}

/* Sample mean of plane a, and the sample covariance of planes a and b with its standard
 * error from the sample's own fourth moments: sqrt((E[(x-mx)^2 (y-my)^2] - C^2) / N). */
static void sample_cov(const uint16_t *a, const uint16_t *b, size_t n, double *ma, double *cov, double *se)
{
    double sa = 0, sb = 0;
    for (size_t i = 0; i < n; i++) { sa += a[i]; sb += b[i]; }
    sa /= n;
    sb /= n;
    double c = 0, c4 = 0;
    for (size_t i = 0; i < n; i++) {
        double p = (a[i] - sa) * (b[i] - sb);
        c += p;
        c4 += p * p;
    }
    c /= n - 1;
    c4 /= n;
    *ma = sa;
    *cov = c;
    *se = sqrt((c4 - c * c) / n);
}

/* Moments sampling against the per-read process's closed form. Read i of the exposure holds
 * Q(t_i), a Poisson process of rate lambda: E Q(t) = lambda t, Cov(Q(t), Q(t')) = lambda
 * min(t, t'); a resultant is the mean of its n reads plus read noise N(0, sigma^2/n), so
 *     E R_r = bias + lambda tbar_r,
 *     Cov(R_r, R_s) = lambda (1/(n_r n_s)) sum_(i in r) sum_(k in s) min(t_i, t_k)
 *                     + [r = s] (sigma^2 / n_r + 1/12),
 * the 1/12 ADU^2 from rounding a value spread over several ADU (gain 1). Over 32768 pixels
 * every mean, variance and neighbouring covariance (and the first against the last) is
 * within 5 standard errors; at 0.3 e-/s every total is below 10 e- (exact Poisson), at
 * 40 e-/s above (the normal). */
START_TEST(moments_covariance_closed_form)
{
    const double rates[] = {0.3, 40.0};
    for (int k = 0; k < 2; k++) {
        wf_readout_config cfg;
        wf_clock clock;
        decoded d;
        flat_run(WF_SAMPLE_MOMENTS, rates[k], 0, 0.0, 256, 128, &cfg, &clock, &d);
        const wf_ma_table *ma = &clock.ma;
        const size_t n = (size_t)d.ncols * d.nrows;
        const double lam = rates[k], s2 = cfg.det.read_noise_e * cfg.det.read_noise_e;
        ck_assert_int_eq(d.nres, ma->nresultants);
        int checked = 0;
        for (int r = 0; r < ma->nresultants; r++) {
            const int nr = ma->first[r + 1] - ma->first[r];
            int others[3] = {r, r + 1, r == 0 ? ma->nresultants - 1 : -1};
            for (int o = 0; o < 3; o++) {
                int s = others[o];
                if (s < 0 || s >= ma->nresultants || (o == 2 && s == r)) continue;
                const int ns = ma->first[s + 1] - ma->first[s];
                double sum = 0.0;
                for (int i = ma->first[r]; i < ma->first[r + 1]; i++)
                    for (int j = ma->first[s]; j < ma->first[s + 1]; j++) {
                        double ti = wf_clock_read_time(&clock, ma->read[i]), tj = wf_clock_read_time(&clock, ma->read[j]);
                        sum += ti < tj ? ti : tj;
                    }
                double want = lam * sum / ((double)nr * ns) + (s == r ? s2 / nr + 1.0 / 12.0 : 0.0);
                double mean, cov, se;
                sample_cov(d.res + (size_t)r * n, d.res + (size_t)s * n, n, &mean, &cov, &se);
                ck_assert_msg(fabs(cov - want) < 5.0 * se, "rate %g, Cov(R%d, R%d) = %.4f, closed form %.4f (se %.4f)",
                              lam, r, s, cov, want, se);
                if (s == r) {
                    double mwant = cfg.det.bias_adu + lam * wf_clock_resultant_time(&clock, r);
                    ck_assert_msg(fabs(mean - mwant) < 5.0 * sqrt(want / n), "rate %g, E R%d = %.4f, closed form %.4f",
                                  lam, r, mean, mwant);
                }
                checked++;
            }
        }
        ck_assert_int_ge(checked, 2 * ma->nresultants);
        free_decoded(&d);
    }
}
END_TEST

/* With nonlinearity f(q) = q + beta q^2 on every read, the mean resultant is
 *     bias + (1/n) sum_i E f(Q(t_i)) = bias + (1/n) sum_i [lambda t_i + beta (lambda^2 t_i^2 + lambda t_i)]
 * (E Q^2 = lambda^2 t^2 + lambda t for a Poisson count). Moments sampling's mean matches it
 * and per-read sampling's within 4 standard errors in every resultant, at a beta large enough
 * that the within-group spread term beta lambda^2 Var_group(t) is itself > 4 of them in the
 * longest group (so leaving it out, as direct sampling does, would fail). */
START_TEST(moments_nonlinearity_mean)
{
    const double lam = 330.0, beta = -2e-6;
    wf_readout_config cfg;
    wf_clock clock;
    decoded d[2];
    flat_run(WF_SAMPLE_MOMENTS, lam, 1, beta, 128, 128, &cfg, &clock, &d[0]);
    flat_run(WF_SAMPLE_PER_READ, lam, 1, beta, 128, 128, &cfg, &clock, &d[1]);
    const wf_ma_table *ma = &clock.ma;
    const size_t n = (size_t)d[0].ncols * d[0].nrows;
    double largest_spread = 0.0, se_there = 0.0;
    for (int r = 0; r < ma->nresultants; r++) {
        const int nr = ma->first[r + 1] - ma->first[r];
        double want = 0.0, tbar = 0.0, tt = 0.0;
        for (int i = ma->first[r]; i < ma->first[r + 1]; i++) {
            double t = wf_clock_read_time(&clock, ma->read[i]);
            want += lam * t + beta * (lam * t * lam * t + lam * t);
            tbar += t;
            tt += t * t;
        }
        want = cfg.det.bias_adu + want / nr;
        tbar /= nr;
        double m[2], v[2], se;
        for (int s = 0; s < 2; s++) sample_cov(d[s].res + (size_t)r * n, d[s].res + (size_t)r * n, n, &m[s], &v[s], &se);
        double se_m = sqrt(v[0] / n), se_diff = sqrt((v[0] + v[1]) / n);
        ck_assert_msg(fabs(m[0] - want) < 4.0 * se_m, "R%d: moments mean %.3f, closed form %.3f (se %.3f)", r, m[0],
                      want, se_m);
        ck_assert_msg(fabs(m[0] - m[1]) < 4.0 * se_diff, "R%d: moments mean %.3f, per-read %.3f (se %.3f)", r, m[0],
                      m[1], se_diff);
        double spread = fabs(beta) * lam * lam * (tt / nr - tbar * tbar);
        if (spread > largest_spread) { largest_spread = spread; se_there = se_diff; }
    }
    ck_assert_msg(largest_spread > 4.0 * se_there, "the spread term %.2f ADU is not resolved (se %.2f)",
                  largest_spread, se_there);
    free_decoded(&d[0]);
    free_decoded(&d[1]);
}
END_TEST

/* Moments sampling: the closed form of a rate changing in time (noiseless, as per-read and
 * direct), and with noise a flat field's per-pixel least-squares slope over the resultants'
 * mean times, averaged over the pixels, is the rate (E R_r = bias + lambda tbar_r makes the
 * slope unbiased) within 5 standard errors of the pixels' scatter. */
START_TEST(linear_rate_moments)
{
    check_linear(WF_SAMPLE_MOMENTS);
    const double lam = 5.0;
    wf_readout_config cfg;
    wf_clock clock;
    decoded d;
    flat_run(WF_SAMPLE_MOMENTS, lam, 0, 0.0, 128, 128, &cfg, &clock, &d);
    const wf_ma_table *ma = &clock.ma;
    const size_t n = (size_t)d.ncols * d.nrows;
    double tb[WF_MA_MAX_RESULTANTS], tm = 0.0, stt = 0.0;
    for (int r = 0; r < ma->nresultants; r++) tm += (tb[r] = wf_clock_resultant_time(&clock, r)) / ma->nresultants;
    for (int r = 0; r < ma->nresultants; r++) stt += (tb[r] - tm) * (tb[r] - tm);
    double s1 = 0.0, s2 = 0.0;
    for (size_t i = 0; i < n; i++) {
        double sty = 0.0;
        for (int r = 0; r < ma->nresultants; r++) sty += (tb[r] - tm) * d.res[(size_t)r * n + i];
        double slope = sty / stt;
        s1 += slope;
        s2 += slope * slope;
    }
    double mean = s1 / n, sd = sqrt(s2 / n - mean * mean);
    ck_assert_msg(fabs(mean - lam) < 5.0 * sd / sqrt((double)n), "slope %.5f e-/s, rate %.5f (se %.5f)", mean, lam,
                  sd / sqrt((double)n));
    free_decoded(&d);
}
END_TEST

/* A rate changing in time only from row 10 on (rows 0-9 constant). */
static wf_status lower_slope(void *ctx, int y0, int y1, int ncols, float *slope, int *any)
{
    const linear_source *l = ctx;
    *any = 0;
    for (int y = y0; y < y1; y++)
        for (int x = 0; x < ncols; x++) {
            slope[(size_t)(y - y0) * ncols + x] = y >= 10 ? (float)l->g : 0.0f;
            *any |= y >= 10;
        }
    return WF_OK;
}

/* Moments sampling of a rate changing in time, with photon noise: each pixel with a slope
 * takes its own interval means, so the mean resultant is the closed form of check_linear
 * within 5 standard errors; a pixel without one is drawn the same whether its tile holds
 * sloped pixels or not, so the bytes do not depend on the tile height. */
START_TEST(moments_time_variable)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 64, 80);
    cfg.sampling = WF_SAMPLE_MOMENTS;
    cfg.time_variable = 1;
    memset(&cfg.det.on, 0, sizeof cfg.det.on);
    cfg.det.on.photon_noise = 1;
    const double r0 = 50.0, g = 0.02;
    linear_source ls = {r0, g};
    wf_scene_source src = {&ls, linear_rate, NULL, lower_slope};
    const int heights[] = {4, 20, 80};
    decoded ref = {0};
    for (int i = 0; i < 3; i++) {
        cfg.tile_rows = heights[i];
        decoded d;
        run_decoded(&cfg, &clock, &src, 1, &d);
        if (i == 0) { ref = d; continue; }
        char what[64];
        snprintf(what, sizeof what, "tile height %d", heights[i]);
        assert_same(&ref, &d, what);
        free_decoded(&d);
    }
    const double T = wf_clock_exposure_time(&clock), tm = 0.5 * T;
    const size_t n = (size_t)ref.ncols * ref.nrows, first = (size_t)10 * ref.ncols, m = n - first;
    for (int r = 0; r < clock.ma.nresultants; r++) {
        int nr = clock.ma.first[r + 1] - clock.ma.first[r];
        double want = 0.0;
        for (int j = clock.ma.first[r]; j < clock.ma.first[r + 1]; j++) {
            double t = wf_clock_read_time(&clock, clock.ma.read[j]);
            want += r0 * t + g * (t * t / 2 - t * tm);
        }
        want = want / nr + cfg.det.bias_adu;
        double mean, var, se;
        const uint16_t *plane = ref.res + (size_t)r * n + first;
        sample_cov(plane, plane, m, &mean, &var, &se);
        ck_assert_msg(fabs(mean - want) < 5.0 * sqrt(var / m), "R%d: mean %.3f, closed form %.3f (se %.3f)", r, mean,
                      want, sqrt(var / m));
    }
    free_decoded(&ref);
}
END_TEST

/* A grid scene behind a wrapper that records the rows it was asked for; instance 1 does not
 * draw its first tile until instance 0 has taken one of its run's (or 10 s have passed), so
 * the fast instance finishes its run and takes the back of the slow one's whatever the
 * machine's scheduling (a fixed delay made this depend on how soon thread 0 got a core). */
typedef struct slow_source {
    wf_scene_source inner;
    int slow;
    _Atomic int max_y0; /* the furthest row asked for */
    _Atomic int *other_max_y0;
    int other_from;     /* the first row of this instance's run */
} slow_source;

static wf_status slow_fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    slow_source *s = ctx;
    if (s->slow)
        for (int i = 0; i < 10000 && *s->other_max_y0 < s->other_from; i++) {
            struct timespec ts = {0, 1000000};
            nanosleep(&ts, NULL);
        }
    if (y0 > s->max_y0) s->max_y0 = y0;
    return s->inner.fill_rate(s->inner.ctx, y0, y1, ncols, rate);
}

START_TEST(tiles_taken_from_a_slow_thread)
{
    wf_readout_config cfg;
    wf_clock clock;
    small_config(&cfg, &clock, 64, 128);
    cfg.mode = WF_MODE_SINGLE;
    cfg.exptime = 300.0;
    cfg.tile_rows = 4; /* 32 tiles, 16 per run */
    wf_scene_grid g = test_grid(cfg.ncols, cfg.nrows);
    wf_scene_source grid;
    ck_assert_int_eq(wf_scene_grid_source(&g, &grid), WF_OK);
    size_t len;
    unsigned char *buf = run_stream(&cfg, &clock, &grid, 1, &len);
    decoded ref, d;
    decode(buf, len, &ref);
    free(buf);

    slow_source ss[2] = {{grid, 0, -1, NULL, 0}, {grid, 1, -1, NULL, 64}};
    ss[1].other_max_y0 = &ss[0].max_y0;
    wf_scene_source scenes[2];
    for (int i = 0; i < 2; i++) scenes[i] = (wf_scene_source){&ss[i], slow_fill, NULL, NULL};
    wf_link_memory mem;
    wf_link link;
    wf_link_memory_open(&mem, &link);
    wf_expose_job job = {0};
    job.ro = cfg;
    job.clock = clock;
    job.noise = (wf_noise){WF_NOISE_PHILOX, cfg.seed, cfg.exposure, cfg.sca};
    job.scenes = scenes;
    job.threads = 2;
    job.link = &link;
    ck_assert_msg(wf_expose_run(&job) == WF_OK, "expose: %s", wf_error_message());
    decode(mem.data, mem.len, &d);
    wf_link_memory_close(&mem);
    /* instance 0's run is rows 0-63; it went on into instance 1's, whose last tiles it took */
    ck_assert_msg(ss[0].max_y0 >= 64, "the fast instance never left its run (furthest row %d)", ss[0].max_y0);
    ck_assert_msg(ss[1].max_y0 < 124, "the slow instance drew its whole run (furthest row %d)", ss[1].max_y0);
    assert_same(&ref, &d, "tiles taken from a slow thread");
    free_decoded(&ref);
    free_decoded(&d);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("readout");
    TCase *tc = tcase_create("readout");
    tcase_set_timeout(tc, 300);
    tcase_add_test(tc, determinism_ramp_per_read);
    tcase_add_test(tc, determinism_ramp_direct);
    tcase_add_test(tc, determinism_ramp_moments);
    tcase_add_test(tc, moments_portable_same_bits);
    tcase_add_test(tc, determinism_single);
    tcase_add_test(tc, memory_fixed_by_tile_not_image);
    tcase_add_test(tc, arena_refuses_past_budget);
    tcase_add_test(tc, arena_host_memory);
    tcase_add_test(tc, arena_host_realloc_grows);
    tcase_add_test(tc, arena_host_alloc_dense_part);
    tcase_add_test(tc, noiseless_flux_conserved);
    tcase_add_test(tc, direct_matches_per_read);
    tcase_add_test(tc, per_read_counts_exact);
    tcase_add_test(tc, saturation_defined);
    tcase_add_test(tc, single_frame_closed_form);
    tcase_add_test(tc, cosmic_ray_count);
    tcase_add_test(tc, cosmic_truth_larger_than_tile);
    tcase_add_test(tc, size_arithmetic_saturates);
    tcase_add_test(tc, time_and_size_limits);
    tcase_add_test(tc, meta_fits_any_detector);
    tcase_add_test(tc, replay_equals_source);
    tcase_add_test(tc, linear_rate_per_read);
    tcase_add_test(tc, linear_rate_direct);
    tcase_add_test(tc, linear_rate_moments);
    tcase_add_test(tc, moments_covariance_closed_form);
    tcase_add_test(tc, moments_nonlinearity_mean);
    tcase_add_test(tc, moments_time_variable);
    tcase_add_test(tc, tiles_taken_from_a_slow_thread);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
