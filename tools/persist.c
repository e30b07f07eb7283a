#include "tools/persist.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "hal/clock.h"
#include "sim/draw/scene.h"
#include "sim/optics/bandpass.h"
#include "tools/pipeline.h"

typedef struct entry {
    uint32_t pixel; /* y * ncols + x */
    uint16_t slot, code;
} entry;

struct wf_persist_history {
    int ncols, nrows, depth;
    double min_stimulus, full_well;
    double dt[WF_PERSIST_DEPTH_MAX];
    size_t count[WF_PERSIST_DEPTH_MAX];
    entry *e; /* sorted by (pixel, slot) once the source is asked for */
    size_t n, cap;
};

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
    free(h->e);
    free(h);
}

#define ROWS 64 /* rows asked of a source at once */

wf_status wf_persist_history_add_source(wf_persist_history *h, const wf_scene_source *src,
                                        double exptime, double dt)
{
    if (h->depth >= WF_PERSIST_DEPTH_MAX)
        return wf_error(WF_ERR_RANGE, "persistence history: more than %d earlier exposures", WF_PERSIST_DEPTH_MAX);
    if (!(exptime > 0) || !(dt >= 0) || !isfinite(dt))
        return wf_error(WF_ERR_RANGE, "persistence history: exposure of %g s ending %g s before", exptime, dt);
    const int nc = h->ncols, slot = h->depth;
    /* a stimulus above 2^16 codes (131 ke-) is kept at the largest: the full well is below */
    const double top = 65535.0 * WF_PERSIST_UNIT;
    float *rate = malloc((size_t)ROWS * nc * sizeof *rate);
    if (!rate) return wf_error(WF_ERR_NOMEM, "out of memory for the persistence history");
    wf_status st = WF_OK;
    for (int y0 = 0; y0 < h->nrows && !st; y0 += ROWS) {
        int y1 = y0 + ROWS < h->nrows ? y0 + ROWS : h->nrows;
        if ((st = src->fill_rate(src->ctx, y0, y1, nc, rate))) break;
        for (size_t i = 0; i < (size_t)(y1 - y0) * nc; i++) {
            double x = rate[i] > 0.0f ? rate[i] * exptime : 0.0;
            if (x > h->full_well) x = h->full_well;
            if (!(x >= h->min_stimulus)) continue;
            if (x > top) x = top;
            if (h->n == h->cap) {
                size_t cap = h->cap ? 2 * h->cap : 4096;
                entry *e = realloc(h->e, cap * sizeof *e);
                if (!e) { st = wf_error(WF_ERR_NOMEM, "out of memory for the persistence history"); break; }
                h->e = e;
                h->cap = cap;
            }
            h->e[h->n++] = (entry){(uint32_t)((size_t)y0 * nc + i), (uint16_t)slot,
                                   (uint16_t)nearbyint(x / WF_PERSIST_UNIT)};
            h->count[slot]++;
        }
    }
    free(rate);
    if (st) return st;
    h->dt[slot] = dt;
    h->depth++;
    return WF_OK;
}

/* Whole flux of an AB magnitude in e-/s, for choosing the objects that could reach the
 * threshold (a pixel never holds more than its object's whole flux). */
static wf_status bright_subset(const wf_catalog *cat, const wf_bandpass *bp, const char *filter,
                               double min_rate, wf_catalog *out, int *any)
{
    int band;
    wf_status st = wf_catalog_band(cat, filter, &band);
    if (st) return st;
    uint32_t *idx = malloc((cat->n ? cat->n : 1) * sizeof *idx);
    if (!idx) return wf_error(WF_ERR_NOMEM, "out of memory for the bright objects");
    size_t n = 0;
    for (size_t i = 0; i < cat->n; i++)
        if (wf_bandpass_countrate_ab(bp, cat->mag[band][i]) >= min_rate) idx[n++] = (uint32_t)i;
    st = wf_catalog_subset(cat, idx, n, out);
    free(idx);
    *any = !st && n > 0;
    return st;
}

wf_status wf_persist_history_add_exposure(wf_persist_history *h, const wf_config *cfg,
                                          const wf_clock *clock, double dt)
{
    double t = cfg->ro.mode == WF_MODE_SINGLE ? cfg->ro.exptime : wf_clock_exposure_time(clock);
    if (cfg->scene_kind == 2) { /* the grid: the same pixels every time */
        wf_scene_grid g;
        wf_scene_source src;
        wf_pipeline_grid(cfg, &g);
        wf_status st = wf_scene_grid_source(&g, &src);
        return st ? st : wf_persist_history_add_source(h, &src, t, dt);
    }
    wf_scene_inputs in;
    memset(&in, 0, sizeof in);
    wf_catalog gal, stars;
    memset(&gal, 0, sizeof gal);
    memset(&stars, 0, sizeof stars);
    int have_gal = 0, have_stars = 0;
    wf_scene *scene = NULL;
    wf_bandpass *bp = malloc(sizeof *bp);
    wf_filter f;
    wf_status st = bp ? wf_filter_parse(cfg->filter, &f) : wf_error(WF_ERR_NOMEM, "out of memory");
    if (!st) st = wf_bandpass_load(f, cfg->data_dir[0] ? cfg->data_dir : NULL, bp);
    if (!st) st = wf_pipeline_load_catalogs(cfg, &in);
    const double min_rate = h->min_stimulus / t;
    if (!st && in.have_gal) st = bright_subset(&in.gal, bp, cfg->filter, min_rate, &gal, &have_gal);
    if (!st && in.have_stars) st = bright_subset(&in.stars, bp, cfg->filter, min_rate, &stars, &have_stars);
    if (!st && (have_gal || have_stars)) {
        wf_scene_setup ss;
        wf_pipeline_scene_setup(cfg, clock, 1, &ss);
        ss.sky_on = 0;
        wf_scene_source src;
        st = wf_scene_create(&ss, have_gal ? &gal : NULL, have_stars ? &stars : NULL, &scene);
        if (!st) st = wf_scene_source_for(scene, 0, &src);
        if (!st) st = wf_persist_history_add_source(h, &src, t, dt);
    } else if (!st) { /* nothing bright: the slot is kept, empty, so slots stay in time order */
        if (h->depth >= WF_PERSIST_DEPTH_MAX)
            st = wf_error(WF_ERR_RANGE, "persistence history: more than %d earlier exposures", WF_PERSIST_DEPTH_MAX);
        else
            h->dt[h->depth++] = dt;
    }
    wf_scene_destroy(scene);
    if (have_gal) wf_catalog_free(&gal);
    if (have_stars) wf_catalog_free(&stars);
    wf_pipeline_inputs_free(&in);
    free(bp);
    return st;
}

static int by_pixel(const void *a, const void *b)
{
    const entry *p = a, *q = b;
    if (p->pixel != q->pixel) return p->pixel < q->pixel ? -1 : 1;
    return (p->slot > q->slot) - (p->slot < q->slot);
}

static wf_status fill(void *ctx, int y0, int y1, int ncols, uint16_t *code)
{
    const wf_persist_history *h = ctx;
    const int d = h->depth;
    memset(code, 0, (size_t)(y1 - y0) * ncols * d * sizeof *code);
    const uint32_t lo = (uint32_t)y0 * (uint32_t)ncols, hi = (uint32_t)y1 * (uint32_t)ncols;
    size_t a = 0, b = h->n; /* first entry at or after lo */
    while (a < b) {
        size_t m = a + (b - a) / 2;
        if (h->e[m].pixel < lo) a = m + 1;
        else b = m;
    }
    for (size_t k = a; k < h->n && h->e[k].pixel < hi; k++)
        code[(size_t)(h->e[k].pixel - lo) * d + h->e[k].slot] = h->e[k].code;
    return WF_OK;
}

void wf_persist_history_source(wf_persist_history *h, wf_persist_source *out)
{
    memset(out, 0, sizeof *out);
    if (h->n) qsort(h->e, h->n, sizeof *h->e, by_pixel);
    if (h->n == 0) return; /* nothing to release: the firmware does nothing at all */
    out->ctx = h;
    out->depth = h->depth;
    memcpy(out->dt, h->dt, sizeof out->dt);
    out->fill = fill;
}

size_t wf_persist_history_pixels(const wf_persist_history *h, int slot)
{
    return slot >= 0 && slot < h->depth ? h->count[slot] : 0;
}
