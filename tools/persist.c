#include "tools/persist.h"

#include "sim/draw/plane_cache.h"

#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hal/clock.h"
#include "sim/draw/scene.h"
#include "sim/optics/bandpass.h"
#include "tools/pipeline.h"

typedef struct entry {
    uint32_t pixel; /* y * ncols + x */
    uint16_t code;
} entry;

/* One earlier exposure's kept pixels, in pixel order (as the rows are scanned). */
typedef struct slot_list {
    entry *e;
    size_t n;
} slot_list;

struct wf_persist_history {
    int ncols, nrows, depth;
    double min_stimulus, full_well;
    double dt[WF_PERSIST_DEPTH_MAX];
    slot_list slot[WF_PERSIST_DEPTH_MAX];
    int own[WF_PERSIST_DEPTH_MAX]; /* 1: freed with the history; 0: the cache's */
    unsigned long held;            /* the cache's tick before its first slot: the entries used
                                    * since are its own, never thrown out while it is built */
};

/* Per SCA, CACHE_DEPTH exposures drawn or made, the earliest thrown out first (cache_find):
 * a history (at most WF_PERSIST_DEPTH_MAX slots, all of its SCA) never loses a slot it holds
 * while it is built, and a run that goes forward in the plan keeps each SCA's recent past
 * (which assumes EXPIDs follow the plan's time, as `wfisim survey plan` numbers them). */
#define CACHE_SCAS 32
#define CACHE_DEPTH WF_PERSIST_DEPTH_MAX

typedef struct cache_entry {
    long long expid;
    slot_list list;
    unsigned long used;  /* 0: empty */
    unsigned long added; /* the tick it came in at (wf_persist_cache_export's mark) */
} cache_entry;

struct wf_persist_cache {
    cache_entry s[CACHE_SCAS][CACHE_DEPTH];
    unsigned long tick;
};

wf_status wf_persist_cache_new(wf_persist_cache **out)
{
    *out = calloc(1, sizeof **out);
    return *out ? WF_OK : wf_error(WF_ERR_NOMEM, "out of memory for the persistence cache");
}

void wf_persist_cache_free(wf_persist_cache *c)
{
    if (!c) return;
    for (int k = 0; k < CACHE_SCAS; k++)
        for (int i = 0; i < CACHE_DEPTH; i++) free(c->s[k][i].list.e);
    free(c);
}

/* The entry of (expid, sca), or NULL; *slot: where a new one goes: an empty one, else the
 * earliest exposure before expid not used after tick `held` (the entries a history being
 * built holds), else the least recently used. Not the least recently used first: a history
 * takes its exposures newest first, so after a full history was drawn that is its newest,
 * which the SCA's next item needs, and each next item then drew all but one again (a run that
 * begins mid-plan, a job array's task, an MPI walk: 22 of 24 drawn for three items at depth
 * 8); the earliest is the one the SCA's later items need least. The least recently used is
 * never one a history holds either: it holds fewer than CACHE_DEPTH, all used since. */
static cache_entry *cache_find(wf_persist_cache *c, long long expid, int sca, unsigned long held, cache_entry **slot)
{
    cache_entry *row = c->s[sca], *lru = &row[0], *early = NULL;
    for (int i = 0; i < CACHE_DEPTH; i++) {
        if (row[i].used && row[i].expid == expid) return &row[i];
        if (row[i].used < lru->used) lru = &row[i];
        if (row[i].used && row[i].used <= held && row[i].expid < expid && (!early || row[i].expid < early->expid))
            early = &row[i];
    }
    *slot = !lru->used || !early ? lru : early;
    return NULL;
}

static void cache_put(wf_persist_cache *c, cache_entry *e, long long expid, slot_list list)
{
    free(e->list.e);
    e->list = list;
    e->expid = expid;
    e->used = e->added = ++c->tick;
}

unsigned long wf_persist_cache_mark(const wf_persist_cache *c)
{
    return c ? c->tick : 0;
}

/* The export: per entry int64 expid, int32 sca, uint32 n, n uint32 pixels, n uint16 codes. */
wf_status wf_persist_cache_export(const wf_persist_cache *c, unsigned long mark, void **buf, size_t *size)
{
    *buf = NULL;
    *size = 0;
    if (!c) return WF_OK;
    size_t total = 0;
    for (int k = 0; k < CACHE_SCAS; k++)
        for (int i = 0; i < CACHE_DEPTH; i++)
            if (c->s[k][i].used && c->s[k][i].added > mark) total += 16 + c->s[k][i].list.n * 6;
    if (!total) return WF_OK;
    unsigned char *p = malloc(total);
    if (!p) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence histories drawn");
    *buf = p;
    *size = total;
    for (int k = 0; k < CACHE_SCAS; k++)
        for (int i = 0; i < CACHE_DEPTH; i++) {
            const cache_entry *e = &c->s[k][i];
            if (!e->used || e->added <= mark) continue;
            int64_t expid = e->expid;
            int32_t sca = k;
            uint32_t n = (uint32_t)e->list.n;
            memcpy(p, &expid, 8);
            memcpy(p + 8, &sca, 4);
            memcpy(p + 12, &n, 4);
            p += 16;
            for (uint32_t j = 0; j < n; j++, p += 4) memcpy(p, &e->list.e[j].pixel, 4);
            for (uint32_t j = 0; j < n; j++, p += 2) memcpy(p, &e->list.e[j].code, 2);
        }
    return WF_OK;
}

wf_status wf_persist_cache_import(wf_persist_cache *c, const void *buf, size_t size)
{
    const unsigned long held = c ? c->tick : 0;
    const unsigned char *p = buf, *end = p + size;
    while (c && p < end) {
        int64_t expid;
        int32_t sca;
        uint32_t n;
        if (end - p < 16) return wf_error(WF_ERR_INPUT, "persistence histories: a record cut short");
        memcpy(&expid, p, 8);
        memcpy(&sca, p + 8, 4);
        memcpy(&n, p + 12, 4);
        p += 16;
        if (sca < 0 || sca >= CACHE_SCAS || (size_t)(end - p) / 6 < n)
            return wf_error(WF_ERR_INPUT, "persistence histories: a record of SCA %d with %u pixels does not fit",
                            (int)sca, (unsigned)n);
        cache_entry *slot;
        /* held: the records of this batch do not go in place of each other */
        if (cache_find(c, expid, sca, held, &slot)) { p += (size_t)n * 6; continue; } /* the same bytes */
        slot_list list = {malloc((n ? n : 1) * sizeof(entry)), n};
        if (!list.e) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence histories");
        for (uint32_t j = 0; j < n; j++) memcpy(&list.e[j].pixel, p + 4 * (size_t)j, 4);
        for (uint32_t j = 0; j < n; j++) memcpy(&list.e[j].code, p + 4 * (size_t)n + 2 * (size_t)j, 2);
        p += (size_t)n * 6;
        cache_put(c, slot, expid, list);
    }
    return WF_OK;
}

wf_status wf_persist_history_new(int ncols, int nrows, double min_stimulus, double full_well,
                                 wf_persist_history **out)
{
    *out = NULL;
    if (ncols < 1 || nrows < 1 || (double)ncols * nrows > 4294967295.0)
        return wf_error(WF_ERR_RANGE, "persistence history: SCA of %d x %d pixels", ncols, nrows);
    if (!(min_stimulus >= WF_PERSIST_UNIT) || !(full_well > 0))
        return wf_error(WF_ERR_RANGE, "persistence history: min_stimulus %g e- (at least %g), full well %g",
                        min_stimulus, WF_PERSIST_UNIT, full_well);
    wf_persist_history *h = calloc(1, sizeof *h);
    if (!h) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence history");
    h->ncols = ncols;
    h->nrows = nrows;
    h->min_stimulus = min_stimulus;
    h->full_well = full_well;
    *out = h;
    return WF_OK;
}

void wf_persist_history_free(wf_persist_history *h)
{
    if (!h) return;
    for (int j = 0; j < h->depth; j++)
        if (h->own[j]) free(h->slot[j].e);
    free(h);
}

#define ROWS 64 /* rows asked of a source at once */

/* Appends the kept pixels of rate[0 .. n) x exptime (pixel0 the first one's index) to *out
 * (*cap entries allocated). */
static wf_status keep_pixels(const float *rate, size_t n, uint32_t pixel0, double exptime, double min_stimulus,
                             double full_well, slot_list *out, size_t *cap)
{
    /* a stimulus above 2^16 codes (131 ke-) is kept at the largest: the full well is below */
    const double top = 65535.0 * WF_PERSIST_UNIT;
    for (size_t i = 0; i < n; i++) {
        double x = rate[i] > 0.0f ? rate[i] * exptime : 0.0;
        if (x > full_well) x = full_well;
        if (!(x >= min_stimulus)) continue;
        if (x > top) x = top;
        if (out->n == *cap) {
            size_t nc2 = *cap ? 2 * *cap : 4096;
            entry *e = realloc(out->e, nc2 * sizeof *e);
            if (!e) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence history");
            out->e = e;
            *cap = nc2;
        }
        out->e[out->n++] = (entry){pixel0 + (uint32_t)i, (uint16_t)nearbyint(x / WF_PERSIST_UNIT)};
    }
    return WF_OK;
}

/* The kept pixels of rate x exptime from src, in pixel order. */
static wf_status scan(const wf_persist_history *h, const wf_scene_source *src, double exptime, slot_list *out)
{
    const int nc = h->ncols;
    size_t cap = 0;
    out->e = NULL;
    out->n = 0;
    float *rate = malloc((size_t)ROWS * nc * sizeof *rate);
    if (!rate) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence history");
    wf_status st = WF_OK;
    for (int y0 = 0; y0 < h->nrows && !st; y0 += ROWS) {
        int y1 = y0 + ROWS < h->nrows ? y0 + ROWS : h->nrows;
        if ((st = src->fill_rate(src->ctx, y0, y1, nc, rate))) break;
        st = keep_pixels(rate, (size_t)(y1 - y0) * nc, (uint32_t)((size_t)y0 * nc), exptime, h->min_stimulus,
                         h->full_well, out, &cap);
    }
    free(rate);
    if (st) { free(out->e); out->e = NULL; out->n = 0; }
    return st;
}

static wf_status add_slot(wf_persist_history *h, slot_list list, int own, double dt)
{
    if (h->depth >= WF_PERSIST_DEPTH_MAX) {
        if (own) free(list.e);
        return wf_error(WF_ERR_RANGE, "persistence history: more than %d earlier exposures", WF_PERSIST_DEPTH_MAX);
    }
    if (!(dt >= 0) || !isfinite(dt)) {
        if (own) free(list.e);
        return wf_error(WF_ERR_RANGE, "persistence history: an exposure ending %g s before", dt);
    }
    h->slot[h->depth] = list;
    h->own[h->depth] = own;
    h->dt[h->depth++] = dt;
    return WF_OK;
}

wf_status wf_persist_history_add_source(wf_persist_history *h, const wf_scene_source *src,
                                        double exptime, double dt)
{
    if (!(exptime > 0))
        return wf_error(WF_ERR_RANGE, "persistence history: exposure of %g s", exptime);
    slot_list list;
    wf_status st = scan(h, src, exptime, &list);
    return st ? st : add_slot(h, list, 1, dt);
}

/* Most of an object's light one 0.11" pixel can hold: psf_peak of a point source (the PSF's
 * own bound, pixel included, wherever the source sits: Y106 0.48, F184 0.22). A galaxy: no
 * more than a point source, nor than its unconvolved profile puts within the circle around a
 * pixel (radius 0.0778"), stretched by 1/q along the minor axis (q the axis ratio from its
 * distortion), plus its knots as point sources. Only a bound: it decides which objects are
 * drawn, never what they give. Point sources drawn with the wide PSF (mag < 15) pass any
 * bound by orders of magnitude. */
#define PSF_PEAK_ANY 1.0 /* before the PSF is built: no pixel holds more than the whole flux
                            (R062 with the built-in pupil puts 60% in one, above the 0.6 this was) */
#define PIXEL_R 0.0778

/* Fraction of a Sersic-n = 1 (exponential) or n = 4 (de Vaucouleurs) profile of half-light
 * radius hlr within radius r: P(2n, b x^(1/n)), b the constant that makes hlr the half. */
static double sersic_within(int n, double hlr, double r)
{
    if (!(hlr > 0)) return 1.0;
    const double a = 2.0 * n, b = n == 1 ? 1.678347 : 7.669249;
    double z = b * pow(r / hlr, 1.0 / n);
    double term = 1.0 / a, sum = term; /* P(a, z) = z^a e^-z / Gamma(a) sum z^k / (a (a+1) .. (a+k)) */
    for (int k = 1; k < 500 && term > 1e-16 * sum; k++) {
        term *= z / (a + k);
        sum += term;
    }
    double p = exp(a * log(z) - z - lgamma(a)) * sum;
    return p < 1.0 ? p : 1.0;
}

double wf_persist_peak_fraction(const wf_catalog *cat, size_t i, double psf_peak)
{
    if (!cat->hlr_disk) return psf_peak;
    double e = hypot(cat->e1[i], cat->e2[i]);
    double q = e < 1.0 ? sqrt((1.0 - e) / (1.0 + e)) : 0.0;
    double r = q > 0.0 ? PIXEL_R / q : INFINITY;
    double bf = cat->bulge_frac[i], kf = cat->knot_frac[i];
    double f = bf * sersic_within(4, cat->hlr_bulge[i], r) + (1.0 - bf) * (1.0 - kf) * sersic_within(1, cat->hlr_disk[i], r) +
               (1.0 - bf) * kf * psf_peak;
    return f < psf_peak ? f : psf_peak;
}

/* The objects of cat one pixel of which could reach min_rate (e-/s) with a PSF whose
 * point-source pixel bound is psf_peak: *n of them, their rows into idx and a 0/1 flag per
 * row into flags (either may be NULL). The one test behind both a history's scene and an
 * exposure's own layer, which must pick the same objects. */
static wf_status pick_bright(const wf_catalog *cat, const wf_bandpass *bp, const char *filter, double psf_peak,
                             double min_rate, uint32_t *idx, uint8_t *flags, size_t *n)
{
    int band;
    wf_status st = wf_catalog_band(cat, filter, &band);
    if (st) return st;
    *n = 0;
    for (size_t i = 0; i < cat->n; i++) {
        const int bright =
            wf_bandpass_countrate_ab(bp, cat->mag[band][i]) * wf_persist_peak_fraction(cat, i, psf_peak) >= min_rate;
        if (flags) flags[i] = (uint8_t)bright;
        if (bright && idx) idx[*n] = (uint32_t)i;
        *n += (size_t)bright;
    }
    return WF_OK;
}

/* The subset of cat pick_bright picks (*any 0, nothing held, when none). */
static wf_status bright_subset(const wf_catalog *cat, const wf_bandpass *bp, const char *filter,
                               double min_rate, double psf_peak, wf_catalog *out, int *any)
{
    *any = 0;
    uint32_t *idx = malloc((cat->n ? cat->n : 1) * sizeof *idx);
    if (!idx) return wf_error(WF_ERR_NOMEM, "out of memory for the bright objects");
    size_t n;
    wf_status st = pick_bright(cat, bp, filter, psf_peak, min_rate, idx, NULL, &n);
    if (!st && n) {
        st = wf_catalog_subset(cat, idx, n, out);
        *any = !st;
    }
    free(idx);
    return st;
}

/* The exposure's bandpass (malloc'd), for the objects' count rates. */
static wf_status load_bandpass(const wf_config *cfg, wf_bandpass **out)
{
    wf_filter f;
    wf_status st = wf_filter_parse(cfg->filter, &f);
    if (st) return st;
    if (!(*out = malloc(sizeof **out))) return wf_error(WF_ERR_NOMEM, "out of memory for a bandpass");
    if ((st = wf_bandpass_load(f, cfg->data_dir[0] ? cfg->data_dir : NULL, *out))) {
        free(*out);
        *out = NULL;
    }
    return st;
}

/* The kept pixels of the exposure cfg describes. */
static wf_status exposure_list(const wf_persist_history *h, const wf_config *cfg, const wf_clock *clock,
                               wf_scene_psf_cache *psfs, slot_list *out)
{
    out->e = NULL;
    out->n = 0;
    double t = wf_pipeline_exptime(cfg, clock);
    if (cfg->scene_kind == 2) { /* the grid: the same pixels every time */
        wf_scene_grid g;
        wf_scene_source src;
        wf_pipeline_grid(cfg, &g);
        wf_status st = wf_scene_grid_source(&g, &src);
        return st ? st : scan(h, &src, t, out);
    }
    wf_scene_inputs in;
    memset(&in, 0, sizeof in);
    wf_catalog gal, stars;
    memset(&gal, 0, sizeof gal);
    memset(&stars, 0, sizeof stars);
    int have_gal = 0, have_stars = 0;
    wf_scene *scene = NULL;
    wf_bandpass *bp = NULL;
    wf_status st = load_bandpass(cfg, &bp);
    if (!st) st = wf_pipeline_load_catalogs(cfg, &in);
    const double min_rate = h->min_stimulus / t;
    /* a PSF is built only when some object could be bright with any PSF (no pixel holds more
     * than the whole flux); the objects are then picked with that PSF's own bound */
    size_t ng = 0, ns = 0;
    if (!st && in.have_gal) st = pick_bright(&in.gal, bp, cfg->filter, PSF_PEAK_ANY, min_rate, NULL, NULL, &ng);
    if (!st && in.have_stars) st = pick_bright(&in.stars, bp, cfg->filter, PSF_PEAK_ANY, min_rate, NULL, NULL, &ns);
    if (!st && ng + ns) {
        wf_scene_setup ss;
        wf_pipeline_scene_setup(cfg, clock, 1, &ss);
        /* drawn to the accuracy of the exposure's own product: at its sky noise, if it had a sky */
        ss.sky_noise = ss.sky_on;
        ss.sky_on = 0;
        ss.psf_cache = psfs;
        st = wf_scene_prepare(&ss, &scene);
        wf_scene_stats stats;
        if (!st) wf_scene_get_stats(scene, &stats);
        if (!st && in.have_gal) st = bright_subset(&in.gal, bp, cfg->filter, min_rate, stats.psf_pixel_max, &gal, &have_gal);
        if (!st && in.have_stars)
            st = bright_subset(&in.stars, bp, cfg->filter, min_rate, stats.psf_pixel_max, &stars, &have_stars);
        if (!st && (have_gal || have_stars)) { /* else nothing bright after all */
            wf_scene_source src;
            st = wf_scene_populate(scene, have_gal ? &gal : NULL, have_stars ? &stars : NULL, ss.sne, ss.nsne);
            if (!st) st = wf_scene_source_for(scene, 0, &src);
            if (!st) st = scan(h, &src, t, out);
        }
    }
    wf_scene_destroy(scene);
    if (have_gal) wf_catalog_free(&gal);
    if (have_stars) wf_catalog_free(&stars);
    wf_pipeline_inputs_free(&in);
    free(bp);
    return st;
}

/* An earlier exposure's slot: from its scene cache entry's layer when find gives one, else
 * drawn. */
static wf_status slot_of(const wf_persist_history *h, const wf_config *cfg, const wf_clock *clock,
                         wf_scene_psf_cache *psfs, wf_persist_plane_fn find, void *find_ctx, int *drawn,
                         slot_list *out)
{
    wf_plane_entry *plane = NULL;
    wf_status st = find ? find(find_ctx, &plane) : WF_OK;
    if (st) return st;
    if (!plane) return exposure_list(h, cfg, clock, psfs, out);
    wf_scene_source src;
    wf_plane_entry_layer_source(plane, &src);
    *drawn = 0;
    st = scan(h, &src, wf_pipeline_exptime(cfg, clock), out);
    wf_plane_entry_close(plane);
    return st;
}

wf_status wf_persist_history_add_exposure(wf_persist_history *h, const wf_config *cfg,
                                          const wf_clock *clock, double dt, wf_persist_cache *cache,
                                          wf_scene_psf_cache *psfs, wf_persist_plane_fn find, void *find_ctx,
                                          int *drawn)
{
    long long expid = cfg->ro.exposure;
    int sca = (int)cfg->ro.sca;
    *drawn = 1;
    if (!cache || sca < 0 || sca >= CACHE_SCAS) {
        slot_list list;
        wf_status st = slot_of(h, cfg, clock, psfs, find, find_ctx, drawn, &list);
        return st ? st : add_slot(h, list, 1, dt);
    }
    if (!h->depth) h->held = cache->tick; /* its first slot */
    cache_entry *slot, *e = cache_find(cache, expid, sca, h->held, &slot);
    if (e) {
        *drawn = 0;
        e->used = ++cache->tick;
    } else {
        slot_list list;
        wf_status st = slot_of(h, cfg, clock, psfs, find, find_ctx, drawn, &list);
        if (st) return st;
        cache_put(cache, slot, expid, list);
        e = slot;
    }
    return add_slot(h, e->list, 0, dt);
}

static wf_status fill(void *ctx, int y0, int y1, int ncols, uint16_t *code)
{
    const wf_persist_history *h = ctx;
    const int d = h->depth;
    memset(code, 0, (size_t)(y1 - y0) * ncols * d * sizeof *code);
    const uint32_t lo = (uint32_t)y0 * (uint32_t)ncols, hi = (uint32_t)y1 * (uint32_t)ncols;
    for (int j = 0; j < d; j++) {
        const entry *e = h->slot[j].e;
        size_t a = 0, b = h->slot[j].n; /* first entry at or after lo */
        while (a < b) {
            size_t m = a + (b - a) / 2;
            if (e[m].pixel < lo) a = m + 1;
            else b = m;
        }
        for (size_t k = a; k < h->slot[j].n && e[k].pixel < hi; k++)
            code[(size_t)(e[k].pixel - lo) * d + j] = e[k].code;
    }
    return WF_OK;
}

void wf_persist_history_source(wf_persist_history *h, wf_persist_source *out)
{
    memset(out, 0, sizeof *out);
    size_t kept = 0;
    for (int j = 0; j < h->depth; j++) kept += h->slot[j].n;
    if (kept == 0) return; /* nothing to release: the firmware does nothing at all */
    out->ctx = h;
    out->depth = h->depth;
    memcpy(out->dt, h->dt, sizeof out->dt);
    out->fill = fill;
}

size_t wf_persist_history_pixels(const wf_persist_history *h, int slot)
{
    return slot >= 0 && slot < h->depth ? h->slot[slot].n : 0;
}

/* ---- an exposure's own slot, from the drawing of its product ----------------------------- */

struct wf_persist_layer {
    int ncols, nrows;
    double exptime, min_stimulus, full_well, min_rate;
    char filter[16];
    wf_bandpass *bp;
    uint8_t *gflags, *sflags;
    pthread_mutex_t lock;
    unsigned char *done; /* per row: its pixels are in rows[y] */
    slot_list *rows;
    int failed;          /* out of memory in a row: nothing goes to the cache */
};

wf_status wf_persist_layer_new(const wf_config *cfg, const wf_clock *clock, double min_stimulus, double full_well,
                               wf_persist_layer **out)
{
    *out = NULL;
    if (!(min_stimulus >= WF_PERSIST_UNIT) || !(full_well > 0))
        return wf_error(WF_ERR_RANGE, "persistence layer: min_stimulus %g e-, full well %g", min_stimulus, full_well);
    wf_persist_layer *l = calloc(1, sizeof *l);
    if (!l) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence layer");
    l->ncols = cfg->ro.ncols;
    l->nrows = cfg->ro.nrows;
    l->exptime = wf_pipeline_exptime(cfg, clock);
    l->min_stimulus = min_stimulus;
    l->full_well = full_well;
    l->min_rate = min_stimulus / l->exptime;
    snprintf(l->filter, sizeof l->filter, "%s", cfg->filter);
    pthread_mutex_init(&l->lock, NULL);
    wf_status st = WF_OK;
    l->done = calloc((size_t)l->nrows, 1);
    l->rows = calloc((size_t)l->nrows, sizeof *l->rows);
    if (!l->done || !l->rows) st = wf_error(WF_ERR_NOMEM, "out of memory for the persistence layer");
    if (!st) st = load_bandpass(cfg, &l->bp);
    if (st) {
        wf_persist_layer_free(l);
        return st;
    }
    *out = l;
    return WF_OK;
}

void wf_persist_layer_free(wf_persist_layer *l)
{
    if (!l) return;
    for (int y = 0; l->rows && y < l->nrows; y++) free(l->rows[y].e);
    free(l->rows);
    free(l->done);
    free(l->gflags);
    free(l->sflags);
    free(l->bp);
    pthread_mutex_destroy(&l->lock);
    free(l);
}

/* A flag per row of cat: the objects bright_subset keeps at psf_peak. */
static wf_status bright_flags(const wf_persist_layer *l, const wf_catalog *cat, double psf_peak, uint8_t **out)
{
    uint8_t *f = calloc(cat->n ? cat->n : 1, 1);
    if (!f) return wf_error(WF_ERR_NOMEM, "out of memory for the bright objects");
    size_t n;
    wf_status st = pick_bright(cat, l->bp, l->filter, psf_peak, l->min_rate, NULL, f, &n);
    if (st) free(f);
    else *out = f;
    return st;
}

wf_status wf_persist_layer_flags(wf_persist_layer *l, const wf_catalog *gal, const wf_catalog *stars,
                                 double psf_pixel_max, const uint8_t **gal_flags, const uint8_t **star_flags)
{
    *gal_flags = *star_flags = NULL;
    wf_status st = WF_OK;
    if (gal && (st = bright_flags(l, gal, psf_pixel_max, &l->gflags))) return st;
    if (stars && (st = bright_flags(l, stars, psf_pixel_max, &l->sflags))) return st;
    *gal_flags = l->gflags;
    *star_flags = l->sflags;
    return WF_OK;
}

double wf_persist_layer_floor(const wf_persist_layer *l)
{
    /* keep_pixels keeps rate x exptime >= min_stimulus: a rate below this never is */
    return l->min_stimulus / l->exptime * (1.0 - 1e-9);
}

void wf_persist_layer_row(void *ctx, int y, const float *rates, int ncols)
{
    wf_persist_layer *l = ctx;
    if (y < 0 || y >= l->nrows || ncols != l->ncols) return;
    slot_list row = {NULL, 0};
    size_t cap = 0;
    int bad = keep_pixels(rates, (size_t)ncols, (uint32_t)((size_t)y * ncols), l->exptime, l->min_stimulus,
                          l->full_well, &row, &cap) != WF_OK;
    pthread_mutex_lock(&l->lock);
    if (bad) l->failed = 1;
    if (!bad && !l->done[y]) {
        l->rows[y] = row;
        l->done[y] = 1;
        row.e = NULL;
    }
    pthread_mutex_unlock(&l->lock);
    free(row.e);
}

wf_status wf_persist_layer_finish(wf_persist_layer *l, wf_persist_cache *cache, long long expid, int sca)
{
    if (!cache || sca < 0 || sca >= CACHE_SCAS || l->failed) return WF_OK;
    size_t n = 0;
    for (int y = 0; y < l->nrows; y++) {
        if (!l->done[y]) return WF_OK; /* not drawn whole (no layer, or a grid): nothing to keep */
        n += l->rows[y].n;
    }
    cache_entry *slot;
    if (cache_find(cache, expid, sca, ULONG_MAX, &slot)) return WF_OK;
    slot_list list = {malloc((n ? n : 1) * sizeof(entry)), n};
    if (!list.e) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence history");
    size_t k = 0;
    for (int y = 0; y < l->nrows; y++) {
        if (l->rows[y].n) memcpy(list.e + k, l->rows[y].e, l->rows[y].n * sizeof(entry));
        k += l->rows[y].n;
    }
    cache_put(cache, slot, expid, list);
    return WF_OK;
}
