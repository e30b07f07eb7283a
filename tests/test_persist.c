/* Persistence (firmware/persistence.c, SPEC §3.1 step 5): GalSim's Fermi model, the charge a
 * saturating star's history releases into a dark exposure against the model integrated in
 * closed form here, Poisson statistics of the released electrons, the DQ mark, the switch
 * (off: the stream's bytes unchanged) and independence of tile height and threads. */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "firmware/persistence.h"
#include "firmware/readout.h"
#include "hal/packet.h"
#include "sim/draw/profile.h"
#include "sim/draw/scene.h"
#include "sim/survey/survey.h"
#include "sim/survey/wcs.h"
#include "tests/testutil.h"
#include "tools/expose.h"
#include "tools/persist.h"

/* GalSim's fermi_linear(x, t) with SPEC §2's numbers, written out on its own */
static double galsim_fermi(double x, double t)
{
    const double A = 0.017, x0 = 6e4, dx = 5e4, a = 0.045, r = 1.0, hw = 5e4;
    if (x > hw) return A * pow(x / x0, a) * pow(t / 1000.0, -r) / (exp(-(x - x0) / dx) + 1.0);
    if (x > 0) return A * pow(hw / x0, a) * pow(t / 1000.0, -r) / (exp(-(hw - x0) / dx) + 1.0) * x / hw;
    return 0.0;
}

START_TEST(model_is_galsims)
{
    wf_persist_config pc;
    wf_persist_defaults(&pc);
    const double xs[] = {-5.0, 0.0, 2.0, 1e4, 4.9999e4, 5e4, 5.0001e4, 6e4, 8e4, 1e5, 3e5};
    for (size_t i = 0; i < sizeof xs / sizeof *xs; i++)
        for (double t = 10.0; t < 1e5; t *= 7.3) {
            double want = galsim_fermi(xs[i], t);
            double got = wf_persist_level(&pc.model, xs[i]) * pow(t / 1000.0, -pc.model.gamma);
            ck_assert_msg(fabs(got - want) <= 1e-14 * want, "x %g t %g: %.17g vs %.17g", xs[i], t, got, want);
        }
    /* the linear tail meets the Fermi part at the half well (GalSim's ps_hf) */
    double below = wf_persist_level(&pc.model, 5e4), above = wf_persist_level(&pc.model, 5e4 * (1 + 1e-12));
    ck_assert_msg(fabs(above - below) < 1e-9 * below, "%.17g vs %.17g", below, above);
    /* the time integral against Simpson's rule (r = 1 has its own closed form) */
    const double gammas[] = {1.0, 0.7, 1.3};
    for (int g = 0; g < 3; g++) {
        double s1 = 37.0, s2 = 421.0, h = (s2 - s1) / 20000, sum = 0.0;
        for (int k = 0; k <= 20000; k++) {
            double w = k == 0 || k == 20000 ? 1 : (k % 2 ? 4 : 2);
            sum += w * pow((s1 + k * h) / 1000.0, -gammas[g]);
        }
        sum *= h / 3.0;
        double got = wf_persist_time_integral(gammas[g], s1, s2);
        ck_assert_msg(fabs(got - sum) < 1e-9 * sum, "gamma %g: %.12g vs %.12g", gammas[g], got, sum);
    }
}
END_TEST

/* ---- a history: a saturating star and a fainter one, in two earlier exposures -------- */

typedef struct star_history {
    int cx, cy;       /* star of slot 0 */
    int fx, fy;       /* star of slot 1 */
} star_history;

/* stimulus in e- of slot j at pixel (x, y): a peak of 1e5 (saturated) falling off */
static double stimulus(const star_history *h, int j, int x, int y)
{
    int dx = j == 0 ? x - h->cx : x - h->fx, dy = j == 0 ? y - h->cy : y - h->fy;
    int r2 = dx * dx + dy * dy;
    if (j == 0) return r2 == 0 ? 1e5 : r2 <= 2 ? 7e4 : r2 <= 8 ? 3e4 : 0.0;
    return r2 <= 1 ? 5.5e4 : 0.0;
}

static wf_status fill_codes(void *ctx, int y0, int y1, int ncols, uint16_t *code)
{
    const star_history *h = ctx;
    for (int y = y0; y < y1; y++)
        for (int x = 0; x < ncols; x++)
            for (int j = 0; j < 2; j++)
                code[((size_t)(y - y0) * ncols + x) * 2 + j] = (uint16_t)(stimulus(h, j, x, y) / WF_PERSIST_UNIT);
    return WF_OK;
}

static star_history hist = {9, 11, 14, 6};

static void dark_config(wf_readout_config *cfg, wf_clock *clock, int n)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->ncols = cfg->nrows = n;
    cfg->tile_rows = 8;
    cfg->mode = WF_MODE_RAMP;
    cfg->exposure = 5;
    cfg->sca = 3;
    cfg->seed = 99;
    wf_detector_defaults(&cfg->det);
    cfg->det.on.dark = cfg->det.on.ipc = cfg->det.on.nonlinearity = cfg->det.on.read_noise = 0;
    cfg->det.on.reciprocity = cfg->det.on.cosmic_rays = 0;
    cfg->det.gain = 0.01; /* 100 ADU per e-: the ADC's rounding is 0.005 e- */
    wf_persist_defaults(&cfg->persist);
    cfg->persist.on = 1;
    cfg->persist.source = (wf_persist_source){.ctx = &hist, .depth = 2, .dt = {95.0, 1500.0}, .fill = fill_codes};
    clock->frame_time = WF_FRAME_TIME_DEFAULT;
    ck_assert_int_eq(wf_ma_builtin("4", &clock->ma), WF_OK);
}

typedef struct decoded {
    int ncols, nrows, nres;
    uint16_t *res;
    float *single;
    uint8_t *sat;
} decoded;

static unsigned char *run_stream(const wf_readout_config *cfg, const wf_clock *clock, wf_noise_kind nk,
                                 int threads, size_t *len)
{
    wf_scene_grid g = {cfg->ncols, cfg->nrows, 0.0, 0.0, 1.0, 8}; /* a dark: no light */
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    return wf_test_expose_stream(cfg, clock, &src, nk, threads, len);
}

static void decode(const unsigned char *buf, size_t len, decoded *d)
{
    memset(d, 0, sizeof *d);
    FILE *f = fmemopen((void *)buf, len, "rb");
    wf_packet_reader rd;
    wf_packet_reader_open(&rd, f, "test stream");
    for (int eof = 0;;) {
        wf_packet_header h;
        const void *p;
        ck_assert_msg(wf_packet_reader_next(&rd, &h, &p, &eof) == WF_OK, "%s", wf_error_message());
        if (eof) break;
        if (h.kind == WF_PK_META) {
            sscanf(strstr(p, "ncols = "), "ncols = %d", &d->ncols);
            sscanf(strstr(p, "nrows = "), "nrows = %d", &d->nrows);
            size_t n = (size_t)d->ncols * d->nrows;
            d->res = calloc(n * WF_MA_MAX_RESULTANTS, 2);
            d->single = calloc(n, 4);
            d->sat = calloc(n, 1);
        } else if (h.kind == WF_PK_RESULTANTS) {
            d->nres = (int)h.nplanes;
            const uint16_t *v = p;
            for (uint32_t r = 0; r < h.nplanes; r++)
                for (uint32_t y = 0; y < h.row_count; y++)
                    memcpy(d->res + ((size_t)r * d->nrows + h.first_row + y) * d->ncols,
                           v + ((size_t)r * h.row_count + y) * h.ncols, h.ncols * 2);
        } else if (h.kind == WF_PK_SINGLE) {
            memcpy(d->single + (size_t)h.first_row * d->ncols, p, (size_t)h.row_count * h.ncols * 4);
        } else if (h.kind == WF_PK_SATURATION) {
            memcpy(d->sat + (size_t)h.first_row * d->ncols, p, (size_t)h.row_count * h.ncols);
        }
    }
    wf_packet_reader_close(&rd);
    fclose(f);
}

static void free_decoded(decoded *d)
{
    free(d->res);
    free(d->single);
    free(d->sat);
}

/* electrons released into pixel (x, y) from the reset to t, GalSim's current integrated
 * by hand: the integral of A f(x) (s/1000)^-1 over s in [dt, dt + t] is A f(x) 1000 ln((dt + t)/dt) */
static double released(int x, int y, double t)
{
    const double dt[2] = {95.0, 1500.0};
    double e = 0.0;
    for (int j = 0; j < 2; j++) {
        double s = stimulus(&hist, j, x, y);
        e += galsim_fermi(s, 1000.0) * 1000.0 * log((dt[j] + t) / dt[j]);
    }
    return e;
}

static void check_closed_form(wf_sampling sampling)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 24);
    cfg.sampling = sampling;
    size_t len;
    unsigned char *buf = run_stream(&cfg, &clock, WF_NOISE_OFF, 1, &len);
    decoded d;
    decode(buf, len, &d);
    free(buf);
    const wf_ma_table *ma = &clock.ma;
    ck_assert_int_eq(d.nres, ma->nresultants);
    int lit = 0;
    double most = 0.0;
    for (int y = 0; y < 24; y++)
        for (int x = 0; x < 24; x++) {
            int hist_here = stimulus(&hist, 0, x, y) > 0 || stimulus(&hist, 1, x, y) > 0;
            lit += hist_here;
            for (int r = 0; r < ma->nresultants; r++) {
                /* the resultant is the mean of its reads' ADU */
                double want = 0.0;
                int n = ma->first[r + 1] - ma->first[r];
                for (int j = ma->first[r]; j < ma->first[r + 1]; j++)
                    want += cfg.det.bias_adu + released(x, y, (ma->read[j] + 1) * clock.frame_time) / cfg.det.gain;
                want /= n;
                double got = d.res[((size_t)r * 24 + y) * 24 + x];
                if (!hist_here) ck_assert_msg(got == cfg.det.bias_adu, "(%d, %d) r %d: %g ADU, no history", x, y, r, got);
                /* each read rounded to an ADU, then the mean: within one ADU (0.01 e-) */
                ck_assert_msg(fabs(got - want) <= 1.0, "(%d, %d) resultant %d: %g ADU, closed form %.3f", x, y, r,
                              got, want);
                if (got - cfg.det.bias_adu > most) most = got - cfg.det.bias_adu;
            }
            /* DQ: marked exactly where there is a history */
            ck_assert_msg(d.sat[y * 24 + x] == (hist_here ? WF_SAT_PERSISTENCE : 255), "(%d, %d) mark %d", x, y,
                          d.sat[y * 24 + x]);
        }
    ck_assert_int_eq(lit, 25 + 5); /* 25 pixels within r^2 <= 8, 5 within 1 of the second star */
    /* the saturated pixel releases ~11 e- over table 4's 139 s: far above the 0.01 e- bound */
    ck_assert_msg(most * cfg.det.gain > 10.0, "only %g e- released", most * cfg.det.gain);
    free_decoded(&d);
}

START_TEST(dark_after_saturating_star_per_read) { check_closed_form(WF_SAMPLE_PER_READ); }
END_TEST
START_TEST(dark_after_saturating_star_direct) { check_closed_form(WF_SAMPLE_DIRECT); }
END_TEST
START_TEST(dark_after_saturating_star_moments) { check_closed_form(WF_SAMPLE_MOMENTS); }
END_TEST

/* Single frame: GalSim's applyPersistence, the current at the mid-time times the exposure */
START_TEST(single_frame_is_galsims)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 24);
    cfg.mode = WF_MODE_SINGLE;
    cfg.exptime = 300.0;
    size_t len;
    unsigned char *buf = run_stream(&cfg, &clock, WF_NOISE_OFF, 1, &len);
    decoded d;
    decode(buf, len, &d);
    free(buf);
    for (int y = 0; y < 24; y++)
        for (int x = 0; x < 24; x++) {
            double e = galsim_fermi(stimulus(&hist, 0, x, y), 95.0 + 150.0) * 300.0 +
                       galsim_fermi(stimulus(&hist, 1, x, y), 1500.0 + 150.0) * 300.0;
            double want = cfg.det.bias_adu + e / cfg.det.gain;
            ck_assert_msg(fabs(d.single[y * 24 + x] - want) <= 0.5, "(%d, %d): %g ADU, GalSim %.3f", x, y,
                          d.single[y * 24 + x], want);
        }
    free_decoded(&d);
}
END_TEST

/* Released electrons are Poisson: over a patch of equal histories, mean and variance of the
 * last read (a resultant of one read at gain 1) agree with the closed-form integral. */
static star_history flat; /* unused ctx: every pixel has the same history */
static wf_status fill_flat(void *ctx, int y0, int y1, int ncols, uint16_t *code)
{
    (void)ctx;
    for (size_t i = 0; i < (size_t)(y1 - y0) * ncols; i++) code[i] = (uint16_t)(9e4 / WF_PERSIST_UNIT);
    return WF_OK;
}

START_TEST(released_electrons_are_poisson)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 64);
    cfg.det.gain = 1.0;
    cfg.persist.source = (wf_persist_source){.ctx = &flat, .depth = 1, .dt = {40.0}, .fill = fill_flat};
    size_t len;
    unsigned char *buf = run_stream(&cfg, &clock, WF_NOISE_PHILOX, 1, &len);
    decoded d;
    decode(buf, len, &d);
    free(buf);
    const wf_ma_table *ma = &clock.ma;
    int last = ma->nresultants - 1;
    ck_assert_int_eq(ma->first[last + 1] - ma->first[last], 1);
    double t = (ma->read[ma->first[last]] + 1) * clock.frame_time;
    double mu = galsim_fermi(9e4, 1000.0) * 1000.0 * log((40.0 + t) / 40.0);
    double s = 0, s2 = 0;
    const int n = 64 * 64;
    for (int i = 0; i < n; i++) {
        double e = d.res[(size_t)last * n + i] - cfg.det.bias_adu;
        s += e;
        s2 += e * e;
    }
    double mean = s / n, var = s2 / n - mean * mean;
    ck_assert_msg(fabs(mean - mu) < 5.0 * sqrt(mu / n), "mean %g, model %g", mean, mu);
    /* the sample variance of a Poisson mean mu has sd ~ mu sqrt(2/n) (+ mu/n) */
    ck_assert_msg(fabs(var - mu) < 5.0 * mu * sqrt(2.0 / n + 1.0 / (mu * n)), "variance %g, mean %g", var, mu);
    free_decoded(&d);
}
END_TEST

/* Off (switch off, or no history) costs nothing: the same arena and the same bytes as a
 * configuration that never heard of persistence. */
START_TEST(off_is_byte_identical)
{
    wf_readout_config base, cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 40);
    cfg.det = (wf_detector){0};
    wf_detector_defaults(&cfg.det); /* every other effect on: a real exposure */
    base = cfg;
    memset(&base.persist, 0, sizeof base.persist);
    size_t nb, no;
    ck_assert_int_eq(wf_readout_arena_need(&base, &clock, &nb), WF_OK);
    cfg.persist.on = 0;
    ck_assert_int_eq(wf_readout_arena_need(&cfg, &clock, &no), WF_OK);
    ck_assert_uint_eq(nb, no);
    size_t lb, lo, le;
    unsigned char *b = run_stream(&base, &clock, WF_NOISE_PHILOX, 1, &lb);
    unsigned char *o = run_stream(&cfg, &clock, WF_NOISE_PHILOX, 1, &lo);
    wf_readout_config empty = cfg;
    empty.persist.on = 1;
    empty.persist.source.depth = 0;
    unsigned char *e = run_stream(&empty, &clock, WF_NOISE_PHILOX, 1, &le);
    ck_assert_msg(lb == lo && !memcmp(b, o, lb), "switched off: the stream changed");
    ck_assert_msg(lb == le && !memcmp(b, e, lb), "no history: the stream changed");
    /* and on, it does change it */
    size_t ln;
    cfg.persist.on = 1;
    unsigned char *on = run_stream(&cfg, &clock, WF_NOISE_PHILOX, 1, &ln);
    ck_assert_msg(ln != lb || memcmp(b, on, lb), "persistence on changed nothing");
    free(b);
    free(o);
    free(e);
    free(on);
}
END_TEST

START_TEST(independent_of_tiles_and_threads)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 24);
    wf_detector_defaults(&cfg.det);
    const int heights[] = {1, 5, 11, 24};
    const wf_sampling samplings[] = {WF_SAMPLE_PER_READ, WF_SAMPLE_DIRECT, WF_SAMPLE_MOMENTS};
    for (int s = 0; s < 3; s++) {
        cfg.sampling = samplings[s];
        unsigned char *ref = NULL;
        size_t lref = 0;
        for (int i = 0; i < 4; i++)
            for (int threads = 1; threads <= 2; threads++) {
                cfg.tile_rows = heights[i];
                size_t len;
                unsigned char *b = run_stream(&cfg, &clock, WF_NOISE_PHILOX, threads, &len);
                if (!ref) { ref = b; lref = len; continue; }
                decoded a, c;
                decode(ref, lref, &a);
                decode(b, len, &c);
                size_t n = 24 * 24;
                ck_assert_msg(!memcmp(a.res, c.res, n * (size_t)a.nres * 2) && !memcmp(a.sat, c.sat, n),
                              "tile height %d, %d threads, sampling %d: output differs", heights[i], threads, s);
                free_decoded(&a);
                free_decoded(&c);
                free(b);
            }
        free(ref);
    }
}
END_TEST

/* Up the ramp a history that ends at the reset (0 s) diverges at r = 1: refused by name. */
START_TEST(zero_gap_refused)
{
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, 8);
    cfg.persist.source.dt[1] = 0.0;
    wf_link_memory mem;
    wf_link link;
    wf_link_memory_open(&mem, &link);
    wf_scene_grid g = {8, 8, 0.0, 0.0, 1.0, 8};
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    wf_expose_job job = {0};
    job.ro = cfg;
    job.clock = clock;
    job.noise = (wf_noise){WF_NOISE_OFF, 1, 1, 1};
    job.scenes = &src;
    job.threads = 1;
    job.link = &link;
    ck_assert_int_eq(wf_expose_run(&job), WF_ERR_RANGE);
    ck_assert_ptr_nonnull(strstr(wf_error_message(), "persistence: earlier exposure 2 ended 0 s"));
    wf_link_memory_close(&mem);
}
END_TEST



/* The host's history (tools/persist.c) from a scene source: a pixel is kept exactly where its
 * charge, rate x exposure time up to the full well, reaches min_stimulus, as that charge in
 * 2 e- codes; the readout then marks exactly those pixels (SATURATION 254 -> DQ PERSISTENCE). */
START_TEST(history_threshold_exact)
{
    const int n = 40;
    wf_scene_grid g = {n, n, 0.0, 2.0e5, 1.2, 16}; /* cores saturate, wings cross 5000 e- */
    wf_scene_source src;
    ck_assert_int_eq(wf_scene_grid_source(&g, &src), WF_OK);
    wf_persist_history *h;
    ck_assert_int_eq(wf_persist_history_new(n, n, 5000.0, 1e5, &h), WF_OK);
    const double T[2] = {294.0, 20.0};
    ck_assert_int_eq(wf_persist_history_add_source(h, &src, T[0], 60.0), WF_OK);
    ck_assert_int_eq(wf_persist_history_add_source(h, &src, T[1], 700.0), WF_OK);
    wf_persist_source ps;
    wf_persist_history_source(h, &ps);
    ck_assert_int_eq(ps.depth, 2);
    float *rate = malloc(sizeof *rate * (size_t)n * n);
    uint16_t *code = malloc(sizeof *code * (size_t)n * n * 2);
    ck_assert_int_eq(src.fill_rate(src.ctx, 0, n, n, rate), WF_OK);
    /* any row range gives the same codes: rows 7..29 against the whole */
    ck_assert_int_eq(ps.fill(ps.ctx, 7, 29, n, code), WF_OK);
    uint16_t *whole = malloc(sizeof *whole * (size_t)n * n * 2);
    ck_assert_int_eq(ps.fill(ps.ctx, 0, n, n, whole), WF_OK);
    ck_assert(!memcmp(code, whole + (size_t)7 * n * 2, sizeof *code * (size_t)22 * n * 2));
    int kept[2] = {0, 0}, sat = 0;
    for (int i = 0; i < n * n; i++)
        for (int j = 0; j < 2; j++) {
            double x = rate[i] * T[j];
            if (x > 1e5) x = 1e5;
            int want = x >= 5000.0 ? (int)nearbyint(x / 2.0) : 0;
            ck_assert_msg(whole[i * 2 + j] == want, "pixel %d slot %d: code %d, want %d", i, j, whole[i * 2 + j], want);
            kept[j] += want > 0;
            sat += want == 50000;
        }
    ck_assert_msg(kept[0] > kept[1] && kept[1] > 0 && sat > 0, "kept %d, %d; %d at the full well", kept[0], kept[1], sat);
    ck_assert_uint_eq(wf_persist_history_pixels(h, 0), (unsigned)kept[0]);
    /* the readout of a dark marks exactly the kept pixels */
    wf_readout_config cfg;
    wf_clock clock;
    dark_config(&cfg, &clock, n);
    cfg.persist.source = ps;
    size_t len;
    unsigned char *buf = run_stream(&cfg, &clock, WF_NOISE_PHILOX, 2, &len);
    decoded d;
    decode(buf, len, &d);
    free(buf);
    for (int i = 0; i < n * n; i++)
        ck_assert_msg(d.sat[i] == (whole[2 * i] || whole[2 * i + 1] ? WF_SAT_PERSISTENCE : 255), "pixel %d: mark %d", i,
                      d.sat[i]);
    free_decoded(&d);
    free(rate);
    free(code);
    free(whole);
    wf_persist_history_free(h);
}
END_TEST

/* The history cache never throws out a slot the history being built holds, whatever order
 * its exposures' EXPIDs come in (the cache puts an exposure in place of the earliest one
 * before it): SCA 1's eight entries full (EXPIDs 20..27), then a history of EXPIDs 5 and 9
 * (a plan whose EXPIDs do not follow its rows), whose 9 must not go in place of its own 5.
 * Its codes are those of the same history built without the cache (a slot thrown out would
 * be read after it was freed: the sanitizers' run says so, a plain run reads what the
 * allocator wrote there). The grid scene: the same bright pixels in every exposure. */
START_TEST(history_cache_keeps_held)
{
    wf_config cfg;
    wf_clock clock;
    wf_config_defaults(&cfg);
    const char *set[] = {"scene.kind=grid", "readout.ncols=48", "readout.nrows=40", "scene.grid.flux=5e4",
                         "scene.grid.spacing=8", "exposure.mode=single", "exposure.sca=1"};
    for (size_t i = 0; i < sizeof set / sizeof *set; i++)
        ck_assert_msg(wf_config_set(&cfg, set[i], NULL) == WF_OK, "%s: %s", set[i], wf_error_message());
    ck_assert_msg(wf_config_finish(&cfg, &clock) == WF_OK, "%s", wf_error_message());
    const int n = 48 * 40;
    wf_persist_cache *cache;
    ck_assert_int_eq(wf_persist_cache_new(&cache), WF_OK);
    wf_persist_history *fill, *h, *ref;
    int drawn;
    ck_assert_int_eq(wf_persist_history_new(48, 40, cfg.persist.min_stimulus, 1e5, &fill), WF_OK);
    for (int e = 27; e >= 20; e--) {
        cfg.ro.exposure = (uint32_t)e;
        ck_assert_int_eq(wf_persist_history_add_exposure(fill, &cfg, &clock, 100.0 * (28 - e), cache, NULL, NULL, NULL, &drawn), WF_OK);
        ck_assert_int_eq(drawn, 1);
    }
    wf_persist_history_free(fill);
    ck_assert_int_eq(wf_persist_history_new(48, 40, cfg.persist.min_stimulus, 1e5, &h), WF_OK);
    ck_assert_int_eq(wf_persist_history_new(48, 40, cfg.persist.min_stimulus, 1e5, &ref), WF_OK);
    const int ids[2] = {5, 9};
    for (int j = 0; j < 2; j++) {
        cfg.ro.exposure = (uint32_t)ids[j];
        ck_assert_int_eq(wf_persist_history_add_exposure(h, &cfg, &clock, 60.0 + 400.0 * j, cache, NULL, NULL, NULL, &drawn), WF_OK);
        ck_assert_int_eq(drawn, 1);
        ck_assert_int_eq(wf_persist_history_add_exposure(ref, &cfg, &clock, 60.0 + 400.0 * j, NULL, NULL, NULL, NULL, &drawn), WF_OK);
    }
    wf_persist_source a, b;
    wf_persist_history_source(h, &a);
    wf_persist_history_source(ref, &b);
    ck_assert_int_eq(a.depth, 2);
    uint16_t *ca = malloc(sizeof *ca * (size_t)n * 2), *cb = malloc(sizeof *cb * (size_t)n * 2);
    ck_assert_int_eq(a.fill(a.ctx, 0, 40, 48, ca), WF_OK);
    ck_assert_int_eq(b.fill(b.ctx, 0, 40, 48, cb), WF_OK);
    int kept = 0;
    for (int i = 0; i < 2 * n; i++) kept += cb[i] > 0;
    ck_assert_int_gt(kept, 20);
    ck_assert(!memcmp(ca, cb, sizeof *ca * (size_t)n * 2));
    free(ca);
    free(cb);
    wf_persist_history_free(h);
    wf_persist_history_free(ref);
    wf_persist_cache_free(cache);
}
END_TEST

/* The bound that picks an earlier exposure's bright objects holds: no drawn pixel of any
 * object, compact or extended, round or sheared, bulge, disk, knots or a star, exceeds its
 * flux x wf_persist_peak_fraction at the scene PSF's own psf_pixel_max, at Y106 and F184
 * (whose peaks differ by 2x); and it is close for the compact ones (not vacuous). */
START_TEST(bright_bound_holds)
{
    enum { NG = 5 * 3 * 3 * 2 * 3 };
    const char *filters[2] = {"Y106", "F184"};
    for (int fi = 0; fi < 2; fi++) {
        wf_scene_setup ss;
        wf_scene_setup_default(&ss);
        ss.ncols = ss.nrows = 512;
        ss.sky_on = 0;
        snprintf(ss.filter, sizeof ss.filter, "%s", filters[fi]);
        const char *data = getenv("WFISIM_DATA");
        if (data && data[0]) snprintf(ss.data_dir, sizeof ss.data_dir, "%s", data);
        wf_focal_plane fp;
        wf_wcs w;
        ck_assert_int_eq(wf_wcs_focal_plane(NULL, &fp), WF_OK);
        ck_assert_int_eq(wf_wcs_for_sca(&fp, ss.ra, ss.dec, ss.pa, ss.sca, &w), WF_OK);
        char gpath[4200], spath[4200];
        snprintf(gpath, sizeof gpath, "%s/bound_gal.csv", wf_test_tmpdir());
        snprintf(spath, sizeof spath, "%s/bound_star.csv", wf_test_tmpdir());
        FILE *f = fopen(gpath, "w");
        ck_assert_ptr_nonnull(f);
        fprintf(f, "id,ra,dec,z,mag_%s,hlr_disk,hlr_bulge,bulge_frac,knot_frac,e1,e2,pa\n", filters[fi]);
        const double hd[5] = {0.02, 0.05, 0.1, 0.3, 1.0}, hb[3] = {0.01, 0.05, 0.2}, bf[3] = {0.0, 0.5, 1.0};
        const double kf[2] = {0.0, WF_PROFILE_MAX_KNOT_FRAC}, e[3] = {0.0, 0.3, 0.7};
        int id = 0;
        for (int a = 0; a < 5; a++)
            for (int b = 0; b < 3; b++)
                for (int c = 0; c < 3; c++)
                    for (int k = 0; k < 2; k++)
                        for (int s = 0; s < 3; s++) {
                            double ra, dec, x = 40.0 + 26.3 * (id % 18), y = 40.0 + 29.7 * (id / 18);
                            ck_assert_int_eq(wf_wcs_pix2world(&w, x, y, &ra, &dec), WF_OK);
                            id++;
                            fprintf(f, "%d,%.12f,%.12f,0.5,20,%g,%g,%g,%g,%g,%g,%d\n", id, ra, dec, hd[a], hb[b], bf[c],
                                    kf[k], e[s] * 0.6, e[s] * 0.8, 17 * id % 180);
                        }
        fclose(f);
        f = fopen(spath, "w");
        ck_assert_ptr_nonnull(f);
        fprintf(f, "id,ra,dec,mag_%s\n", filters[fi]);
        for (int i = 0; i < 16; i++) { /* every quarter-pixel phase */
            double ra, dec;
            ck_assert_int_eq(wf_wcs_pix2world(&w, 100.0 + 20 * i + 0.25 * (i % 4), 480.0 + 0.25 * (i / 4), &ra, &dec),
                             WF_OK);
            fprintf(f, "%d,%.12f,%.12f,20\n", 1000 + i, ra, dec);
        }
        fclose(f);
        wf_catalog gal, stars;
        ck_assert_msg(wf_catalog_read_galaxies(gpath, &gal) == WF_OK, "%s", wf_error_message());
        ck_assert_msg(wf_catalog_read_stars(spath, &stars) == WF_OK, "%s", wf_error_message());
        ck_assert_int_eq((int)gal.n, NG);
        wf_scene *scene;
        ck_assert_msg(wf_scene_create(&ss, &gal, &stars, &scene) == WF_OK, "%s", wf_error_message());
        wf_scene_stats st;
        wf_scene_get_stats(scene, &st);
        ck_assert_msg(st.psf_pixel_max > 0.1 && st.psf_pixel_max < 0.6, "psf_pixel_max %g", st.psf_pixel_max);
        double worst = 0.0, worst_star = 0.0;
        const size_t nob = wf_scene_object_count(scene);
        ck_assert_int_eq((int)nob, NG + 16);
        for (size_t k = 0; k < nob; k++) {
            wf_scene_object info;
            int x0, y0, nx, ny;
            double *pix;
            ck_assert_msg(wf_scene_draw_object(scene, k, &info, &x0, &y0, &nx, &ny, &pix) == WF_OK, "%s",
                          wf_error_message());
            double peak = 0.0;
            for (long q = 0; q < (long)nx * ny; q++) peak = fmax(peak, pix[q]);
            free(pix);
            const int star = info.kind == 1;
            const size_t i = star ? (size_t)(info.id - 1000) : (size_t)(info.id - 1);
            const double bound = wf_persist_peak_fraction(star ? &stars : &gal, i, st.psf_pixel_max);
            const double ratio = peak / (info.flux * bound);
            ck_assert_msg(ratio <= 1.0 + 1e-6, "%s: object %lld (kind %d): brightest pixel %.6g of its flux, bound %.6g",
                          filters[fi], info.id, info.kind, peak / info.flux, bound);
            if (star) worst_star = fmax(worst_star, ratio);
            else worst = fmax(worst, ratio);
        }
        printf("%s: psf_pixel_max %.4f; brightest pixel / bound: galaxies %.3f, stars %.3f at most\n", filters[fi],
               st.psf_pixel_max, worst, worst_star);
        ck_assert_msg(worst > 0.5 && worst_star > 0.9, "the bound is loose: %g, %g", worst, worst_star);
        wf_scene_destroy(scene);
        wf_catalog_free(&gal);
        wf_catalog_free(&stars);
    }
}
END_TEST

/* ---- survey run: the history from the plan ------------------------------------------- */

#define SMALL "--set readout.ncols=128 --set readout.nrows=96 --set detector.cr_rate=0"
#define NODATA "env -u WFISIM_DATA "

/* An image HDU of a product (tile-compressed or not), as doubles. */
static double *read_hdu(const char *path, const char *name, int type_ok)
{
    (void)type_ok;
    fitsfile *f;
    int status = 0;
    fits_open_file(&f, path, READONLY, &status);
    fits_movnam_hdu(f, ANY_HDU, (char *)name, 0, &status);
    double *v = calloc(128 * 96, sizeof *v);
    int anynul = 0;
    fits_read_img(f, TDOUBLE, 1, 128 * 96, NULL, v, &anynul, &status);
    fits_close_file(f, &status);
    ck_assert_msg(status == 0, "%s: HDU %s unreadable (%d)", path, name, status);
    return v;
}

/* A bright star (AB 16: ~1.5e4 e-/s, saturating its peak in 294 s) at pixel (40 + 15 (e - 2), 48)
 * of SCA 3 in each of exposures 2..5 of a one-visit plan: exposure 5's history holds the other
 * three (ended 56, 406, 756 s before it) and its DQ marks their pixels. The product of exposure
 * 5 is the same bytes made alone, after 4, or among 2..5, whatever the tile height and threads. */
START_TEST(survey_history_any_split)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], stars[4200];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    snprintf(stars, sizeof stars, "%s/stars.csv", d);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey plan --quiet --set survey.visits=1 --out %s", bin, plan), 0);
    wf_survey_row *rows;
    size_t nrows;
    ck_assert_int_eq(wf_survey_read_plan(plan, &rows, &nrows), WF_OK);
    wf_focal_plane fp;
    ck_assert_int_eq(wf_wcs_focal_plane(NULL, &fp), WF_OK);
    FILE *f = fopen(stars, "w");
    fprintf(f, "id,ra,dec,mag_Y106,mag_J129,mag_H158,mag_F184\n");
    for (int e = 2; e <= 5; e++) {
        wf_wcs w;
        double ra, dec;
        ck_assert_int_eq(rows[e].expid, e);
        ck_assert_int_eq(wf_wcs_for_sca(&fp, rows[e].ra, rows[e].dec, rows[e].pa, 3, &w), WF_OK);
        ck_assert_int_eq(wf_wcs_pix2world(&w, 40 + 15 * (e - 2), 48, &ra, &dec), WF_OK);
        fprintf(f, "%d,%.10f,%.10f,16,16,16,16\n", e, ra, dec);
    }
    fclose(f);
    free(rows);
    const char *scene = "--set scene.kind=catalog --set scene.stars=";
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 2:5 --scas 3 " SMALL " %s%s --out %s/a",
                                 bin, plan, scene, stars, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 5 --scas 3 " SMALL " %s%s --out %s/b",
                                 bin, plan, scene, stars, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 4:5 --scas 3 " SMALL
                                 " --set readout.tile_rows=7 --set run.threads=2 %s%s --out %s/c", bin, plan, scene, stars, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 5 --scas 3 " SMALL
                                 " --set detector.effects.persistence=false %s%s --out %s/off", bin, plan, scene, stars, d), 0);
    /* without photon noise (released electrons are then their means) for the slope */
    const char *quiet = "--set detector.effects.photon_noise=false";
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 5 --scas 3 " SMALL " %s %s%s --out %s/qa",
                                 bin, plan, quiet, scene, stars, d), 0);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures 5 --scas 3 " SMALL
                                 " --set detector.effects.persistence=false %s %s%s --out %s/qoff", bin, plan, quiet, scene,
                                 stars, d), 0);
    char a[4300], b[4300], c[4300], off[4300], qa[4300], qoff[4300];
    snprintf(qa, sizeof qa, "%s/qa/wfisim_e000005_sca03.fits", d);
    snprintf(qoff, sizeof qoff, "%s/qoff/wfisim_e000005_sca03.fits", d);
    snprintf(a, sizeof a, "%s/a/wfisim_e000005_sca03.fits", d);
    snprintf(b, sizeof b, "%s/b/wfisim_e000005_sca03.fits", d);
    snprintf(c, sizeof c, "%s/c/wfisim_e000005_sca03.fits", d);
    snprintf(off, sizeof off, "%s/off/wfisim_e000005_sca03.fits", d);
    wf_test_assert_same_file(a, b);
    wf_test_assert_same_file(a, c);
    double *dq = read_hdu(a, "DQ", 0), *dq_off = read_hdu(off, "DQ", 0);
    double *sci = read_hdu(qa, "SCI", 0), *sci_off = read_hdu(qoff, "SCI", 0);
    int marked = 0, far = 0;
    for (int y = 0; y < 96; y++)
        for (int x = 0; x < 128; x++) {
            unsigned v = (unsigned)dq[y * 128 + x];
            ck_assert_msg(!((unsigned)dq_off[y * 128 + x] & 32u), "(%d, %d) marked with persistence off", x, y);
            if (!(v & 32u)) continue;
            marked++;
            /* only around the earlier stars (40, 55, 70; 48); the wide PSF's spikes reach further */
            int near = 0;
            for (int e = 2; e <= 4; e++) near |= abs(x - (40 + 15 * (e - 2))) <= 12 && abs(y - 48) <= 12;
            far += !near;
        }
    ck_assert_msg(marked >= 3 * 9, "%d pixels marked", marked);
    ck_assert_msg(far <= marked / 10, "%d of %d marked pixels away from the earlier stars", far, marked);
    /* the earlier stars' saturated peaks release into this exposure: its slope gains the
     * model's mean current over the ramp, for exposure 4's peak (56 s before) 12 e- x
     * ln(350 / 56) / 294 s = 0.075 e-/s (the same read noise in both runs cancels). The
     * ramp is not a line (the current falls 6x over it at 56 s): the fit's slope is the
     * mean to within 10% (measured 0.96-1.06), bounds 0.8-1.25 */
    for (int e = 2; e <= 4; e++) {
        int i = 48 * 128 + 40 + 15 * (e - 2);
        ck_assert_msg((unsigned)dq[i] & 32u, "exposure %d's star pixel not marked", e);
        double gain = sci[i] - sci_off[i];
        double dt = e == 4 ? 55.9 : e == 3 ? 405.9 : 755.9;
        double mean = galsim_fermi(1e5, 1000.0) * 1000.0 * log((dt + 294.0) / dt) / 294.0;
        printf("survey: exposure %d's peak %.1f s before: slope up %.4f e-/s, model mean current %.4f, %d pixels marked\n", e,
               dt, gain, mean, marked);
        ck_assert_msg(gain > 0.8 * mean && gain < 1.25 * mean, "exposure %d's peak: slope up %g e-/s, model mean %g", e,
                      gain, mean);
    }
    free(dq);
    free(dq_off);
    free(sci);
    free(sci_off);
}
END_TEST

/* A plan slot shorter than its read pattern: F184's 900 s exposures are read by MA table 11
 * for 977 s, with 50 s of slew to the next, so the earlier one's last read comes 27 s after
 * the later one's planned start. The later exposure then begins one frame (its reset) after
 * that read: its history says so, and the run does not stop at an exposure "ending -27 s
 * before". */
START_TEST(survey_ramp_longer_than_slot)
{
    const char *bin = wf_test_program();
    WF_SKIP_UNLESS(bin, "the wfisim program ($WFISIM_BIN)");
    const char *d = wf_test_tmpdir();
    char plan[4200], prod[4300];
    snprintf(plan, sizeof plan, "%s/plan.fits", d);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey plan --quiet --set survey.visits=1 --out %s", bin, plan), 0);
    wf_survey_row *rows;
    size_t nrows;
    ck_assert_int_eq(wf_survey_read_plan(plan, &rows, &nrows), WF_OK);
    size_t e = 0;
    while (e + 1 < nrows && !(strcmp(rows[e].filter, "F184") == 0 && strcmp(rows[e + 1].filter, "F184") == 0)) e++;
    ck_assert_uint_lt(e + 1, nrows);
    const double slot = (rows[e + 1].mjd_start - rows[e].mjd_start) * 86400.0;
    ck_assert_msg(slot < 977.0 - 20.0, "F184 slot %g s: the premise (shorter than MA table 11) is gone", slot);
    const int later = rows[e + 1].expid, earlier = rows[e].expid;
    free(rows);
    ck_assert_int_eq(wf_test_run(NODATA "%s survey run --quiet --plan %s --exposures %d --scas 3 --mode ramp " SMALL
                                 " --out %s/r", bin, plan, later, d), 0);
    snprintf(prod, sizeof prod, "%s/r/wfisim_e%06d_sca03.fits", d, later);
    fitsfile *f = NULL;
    int status = 0;
    long ex = -1;
    double frame = 0.0, dt = -1.0;
    char comment[FLEN_COMMENT], table[FLEN_VALUE];
    fits_open_file(&f, prod, READONLY, &status);
    fits_read_key(f, TLONG, "PERSEX1", &ex, comment, &status);
    fits_read_key(f, TDOUBLE, "FRAMTIME", &frame, NULL, &status);
    fits_read_key(f, TSTRING, "MA_TABLE", table, NULL, &status);
    fits_close_file(f, &status);
    ck_assert_int_eq(status, 0);
    ck_assert_int_eq(ex, earlier);
    ck_assert_str_eq(table, "11");
    ck_assert_msg(sscanf(comment, "its EXPID; ended %lf s before start", &dt) == 1, "PERSEX1 comment '%s'", comment);
    ck_assert_msg(fabs(dt - frame) < 1e-3, "earlier F184 exposure ended %g s before, want one frame %g s", dt, frame);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("persist");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, model_is_galsims);
    tcase_add_test(tc, dark_after_saturating_star_per_read);
    tcase_add_test(tc, dark_after_saturating_star_direct);
    tcase_add_test(tc, dark_after_saturating_star_moments);
    tcase_add_test(tc, single_frame_is_galsims);
    tcase_add_test(tc, released_electrons_are_poisson);
    tcase_add_test(tc, off_is_byte_identical);
    tcase_add_test(tc, independent_of_tiles_and_threads);
    tcase_add_test(tc, zero_gap_refused);
    tcase_add_test(tc, history_threshold_exact);
    tcase_add_test(tc, history_cache_keeps_held);
    tcase_add_test(tc, bright_bound_holds);
    tcase_add_test(tc, survey_history_any_split);
    tcase_add_test(tc, survey_ramp_longer_than_slot);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
