#include "sim/draw/render.h"

#include <limits.h>
#include "hal/arena.h"
#include <stdlib.h>
#include <string.h>

#define NO_STAMP ((size_t)-1)

struct wf_renderer {
    wf_renderer_config cfg;
    wf_render_object *objs; /* on-SCA objects sorted by (y0, id) */
    size_t n;
    wf_draw_fn draw;
    void *draw_ctx;
    size_t *stamp_off;      /* per object: offset in the pool of its first kept row, or NO_STAMP */
    int *stamp_row0;        /* per object: its first kept row (the rows above it were passed) */
    size_t *active;         /* objects admitted and not yet passed, in sorted order */
    size_t nactive;
    size_t next;            /* first object not yet admitted */
    int last_start;
    unsigned char *pool;
    size_t pool_used;
    size_t live_bytes;      /* bytes of the stamps still kept: pool_used - live_bytes is garbage */
    size_t *order;          /* compaction scratch: active objects by offset */
    double *acc, *piece, *skyrow, *hbuf, *lacc, *sacc;
    size_t acc_cap, piece_cap, hbuf_cap, lacc_cap, sacc_cap;
    float *plane, *lplane; /* the request's plane rows and layer rows (plane_get, plane_put) */
    size_t plane_cap, lplane_cap;
    wf_renderer_stats stats;
};

static int by_row(const void *a, const void *b)
{
    const wf_render_object *p = a, *q = b;
    if (p->y0 != q->y0) return p->y0 < q->y0 ? -1 : 1;
    return p->id < q->id ? -1 : p->id > q->id;
}

/* Stamps are drawn in double and kept as float (7 significant digits, far below any noise;
 * half the memory). Pool bytes of a kept stamp from row y0 on, rounded up so that the next
 * stamp can be drawn in double at an aligned address: its passed rows leave the pool at the
 * next compaction, so that a tall stamp the tiles are halfway through holds only its lower
 * half (kept whole, such stamps filled the pool and the next large one was drawn in pieces). */
static size_t kept_bytes(const wf_render_object *o, int y0)
{
    return ((size_t)(o->by0 + o->bny - y0) * (size_t)o->bnx * sizeof(float) + 7u) & ~(size_t)7u;
}

static size_t draw_bytes(const wf_render_object *o)
{
    return (size_t)o->bnx * (size_t)o->bny * sizeof(double);
}

/* Doubles to floats in place: float k lands at bytes [4k, 4k+4), below double k+1's, so
 * nothing is overwritten before it is read. Whole stamps and pieces both go through it, so a
 * row is the same whichever way it was drawn. */
static const float *to_float_in_place(double *buf, size_t n)
{
    float *f = (float *)(void *)buf;
    for (size_t k = 0; k < n; k++) {
        float v = (float)buf[k];
        memcpy(f + k, &v, sizeof v);
    }
    return f;
}

wf_status wf_renderer_create(const wf_renderer_config *cfg, const wf_render_object *objs,
                             size_t n, wf_draw_fn draw, void *draw_ctx, wf_renderer **out)
{
    *out = NULL;
    if (cfg->ncols < 1 || cfg->nrows < 1)
        return wf_error(WF_ERR_RANGE, "renderer: SCA of %d x %d pixels", cfg->ncols, cfg->nrows);
    wf_renderer *r = calloc(1, sizeof *r);
    if (!r) return wf_error(WF_ERR_NOMEM, "renderer: out of memory");
    r->cfg = *cfg;
    if (!r->cfg.max_row_bytes) r->cfg.max_row_bytes = cfg->pool_bytes / 4 + (1u << 20);
    r->draw = draw;
    r->draw_ctx = draw_ctx;
    r->last_start = INT_MIN;
    r->objs = malloc((n ? n : 1) * sizeof *r->objs);
    r->stamp_off = malloc((n ? n : 1) * sizeof *r->stamp_off);
    r->stamp_row0 = malloc((n ? n : 1) * sizeof *r->stamp_row0);
    r->active = malloc((n ? n : 1) * sizeof *r->active);
    r->order = malloc((n ? n : 1) * sizeof *r->order);
    r->pool = cfg->pool_bytes ? wf_arena_host_alloc(cfg->pool_bytes) : NULL;
    r->skyrow = malloc((size_t)cfg->ncols * sizeof *r->skyrow);
    if (!r->objs || !r->stamp_off || !r->stamp_row0 || !r->active || !r->order || (cfg->pool_bytes && !r->pool) || !r->skyrow) {
        wf_renderer_destroy(r);
        return wf_error(WF_ERR_NOMEM, "renderer: cannot reserve %zu objects and a %zu-byte pool", n,
                        cfg->pool_bytes);
    }
    for (size_t i = 0; i < n; i++) {
        const wf_render_object *o = &objs[i];
        if (o->nx < 1 || o->ny < 1) {
            wf_renderer_destroy(r);
            return wf_error(WF_ERR_INPUT, "renderer: object %llu has an empty stamp (%d x %d)",
                            (unsigned long long)o->id, o->nx, o->ny);
        }
        int off = o->x0 >= cfg->ncols || (long)o->x0 + o->nx <= 0 || o->y0 >= cfg->nrows ||
                  (long)o->y0 + o->ny <= 0;
        if (off) { r->stats.objects_skipped++; continue; }
        wf_render_object c = *o;
        if (c.rel_slope != 0.0) c.variable = 1;
        if (c.layer && c.variable) {
            wf_renderer_destroy(r);
            return wf_error(WF_ERR_INPUT, "renderer: object %llu varies, so it cannot be in the layer",
                            (unsigned long long)o->id);
        }
        if (!c.bnx) c.bx0 = c.x0, c.by0 = c.y0, c.bnx = c.nx, c.bny = c.ny;
        const char *bad = NULL;
        if (c.bnx < 1 || c.bny < 1 || c.bx0 < c.x0 || c.by0 < c.y0 || (long)c.bx0 + c.bnx > (long)c.x0 + c.nx ||
            (long)c.by0 + c.bny > (long)c.y0 + c.ny)
            bad = "is not within its footprint";
        else if (!c.halo && (c.bx0 != c.x0 || c.by0 != c.y0 || c.bnx != c.nx || c.bny != c.ny))
            bad = "is smaller than its footprint, but nothing adds the rest (no halo)";
        else if (c.halo && !cfg->halo)
            bad = "has a halo, but the renderer has no halo function";
        if (bad) {
            wf_renderer_destroy(r);
            return wf_error(WF_ERR_INPUT, "renderer: object %llu: box %d x %d at (%d, %d) %s (%d x %d at (%d, %d))",
                            (unsigned long long)o->id, c.bnx, c.bny, c.bx0, c.by0, bad, c.nx, c.ny, c.x0, c.y0);
        }
        r->stats.objects_kept++;
        if (!cfg->plane_get || c.variable) r->objs[r->n++] = c; /* else the plane has it */
    }
    qsort(r->objs, r->n, sizeof *r->objs, by_row);
    for (size_t i = 0; i < r->n; i++) r->stamp_off[i] = NO_STAMP;
    *out = r;
    return WF_OK;
}

void wf_renderer_destroy(wf_renderer *r)
{
    if (!r) return;
    free(r->objs);
    free(r->stamp_off);
    free(r->stamp_row0);
    free(r->active);
    free(r->order);
    free(r->pool);
    free(r->acc);
    free(r->piece);
    free(r->skyrow);
    free(r->hbuf);
    free(r->lacc);
    free(r->sacc);
    free(r->plane);
    free(r->lplane);
    free(r);
}

void wf_renderer_get_stats(const wf_renderer *r, wf_renderer_stats *out) { *out = r->stats; }

/* Makes *bufp (a pointer to elements of `size` bytes) hold count of them. */
static wf_status grow_to(void *bufp, size_t *cap, size_t count, size_t size, const char *what)
{
    if (count <= *cap) return WF_OK;
    /* the contents need not survive: every use writes before it reads */
    void *old, *p;
    memcpy(&old, bufp, sizeof old);
    if (!(p = wf_arena_host_realloc(old, 0, count * size)))
        return wf_error(WF_ERR_NOMEM, "renderer: cannot grow the %s to %zu values", what, count);
    memcpy(bufp, &p, sizeof p);
    *cap = count;
    return WF_OK;
}
#define grow(buf, cap, count, what) grow_to((buf), (cap), (count), sizeof **(buf), (what))

/* Moves the live stamps' kept rows to the front of the pool (they are plain arrays: offsets
 * change, contents do not). Live stamps belong to active objects only. */
static void compact(wf_renderer *r)
{
    size_t n = 0;
    for (size_t a = 0; a < r->nactive; a++)
        if (r->stamp_off[r->active[a]] != NO_STAMP) r->order[n++] = r->active[a];
    /* the active list is nearly in offset order already (stamps are stored as objects are
     * admitted, in the same order), so insertion sort is close to linear */
    for (size_t i = 1; i < n; i++) {
        size_t v = r->order[i], off = r->stamp_off[v], j = i;
        while (j > 0 && r->stamp_off[r->order[j - 1]] > off) {
            r->order[j] = r->order[j - 1];
            j--;
        }
        r->order[j] = v;
    }
    size_t used = 0;
    for (size_t k = 0; k < n; k++) {
        size_t obj = r->order[k], off = r->stamp_off[obj];
        const wf_render_object *o = &r->objs[obj];
        /* the rows exactly: a kept part may start mid-way through a stamp's rounding */
        size_t rows = (size_t)(o->by0 + o->bny - r->stamp_row0[obj]) * (size_t)o->bnx * sizeof(float);
        if (off != used) memmove(r->pool + used, r->pool + off, rows);
        r->stamp_off[obj] = used;
        used += kept_bytes(o, r->stamp_row0[obj]);
    }
    r->pool_used = used;
}

/* A pointer to rows [ya, yb) of object i's box: the cached whole box when it fits the pool,
 * else a piece drawn now. */
static wf_status stamp_rows(wf_renderer *r, size_t i, int ya, int yb, const float **rows)
{
    const wf_render_object *o = &r->objs[i];
    size_t bytes = kept_bytes(o, o->by0), dbytes = draw_bytes(o);
    if (r->stamp_off[i] == NO_STAMP && dbytes <= r->cfg.pool_bytes) {
        /* compact only when that makes room: a futile compaction per request would cost
         * O(active) each time on a crowded tile. The pool is used up to twice what is live
         * (4 MiB at least) before it is compacted, not to its end: every page the bump
         * allocation reaches becomes resident and costs a fault, while moving the live
         * stamps down costs about one copy of what is drawn. */
        size_t soft = 2 * (r->live_bytes + dbytes);
        if (soft < ((size_t)4 << 20)) soft = (size_t)4 << 20;
        if (soft > r->cfg.pool_bytes) soft = r->cfg.pool_bytes;
        if (r->pool_used + dbytes > soft && r->live_bytes + dbytes <= r->cfg.pool_bytes) compact(r);
        if (r->pool_used + dbytes <= r->cfg.pool_bytes) {
            double *dst = (double *)(void *)(r->pool + r->pool_used);
            wf_status st = r->draw(r->draw_ctx, o, o->by0, o->by0 + o->bny, dst);
            if (st) return st;
            to_float_in_place(dst, (size_t)o->bnx * (size_t)o->bny);
            r->stamp_off[i] = r->pool_used;
            r->stamp_row0[i] = o->by0;
            r->pool_used += bytes;
            r->live_bytes += bytes;
            if (r->pool_used > r->stats.pool_high_water) r->stats.pool_high_water = r->pool_used;
            if (r->live_bytes > r->stats.live_high_water) r->stats.live_high_water = r->live_bytes;
            r->stats.stamps_drawn++;
        }
    }
    if (r->stamp_off[i] != NO_STAMP) {
        *rows = (const float *)(const void *)(r->pool + r->stamp_off[i]) + (size_t)(ya - r->stamp_row0[i]) * o->bnx;
        return WF_OK;
    }
    size_t need = (size_t)(yb - ya) * (size_t)o->bnx;
    if (need * sizeof(double) > r->cfg.max_row_bytes)
        return wf_error(WF_ERR_NOMEM, "renderer: object %llu needs %zu bytes for %d rows, above the "
                        "piece limit of %zu", (unsigned long long)o->id, need * sizeof(double), yb - ya,
                        r->cfg.max_row_bytes);
    wf_status st = grow(&r->piece, &r->piece_cap, need, "piece buffer");
    if (st) return st;
    if ((st = r->draw(r->draw_ctx, o, ya, yb, r->piece))) return st;
    r->stats.pieces_drawn++;
    *rows = to_float_in_place(r->piece, need);
    return WF_OK;
}

/* A halo object's rows, one at a time: its box's pixels within the footprint's columns
 * [xa, xb), for the halo function to add with the halo. */
typedef struct halo_view {
    int ba, bb, ca, cb; /* box rows and columns within the footprint */
    const float *src;   /* the box's rows [ba, bb) from column ca */
} halo_view;

static wf_status halo_open(wf_renderer *r, size_t i, int ya, int yb, int xa, int xb, halo_view *h)
{
    const wf_render_object *o = &r->objs[i];
    *h = (halo_view){o->by0 > ya ? o->by0 : ya, o->by0 + o->bny < yb ? o->by0 + o->bny : yb,
                     o->bx0 > xa ? o->bx0 : xa, o->bx0 + o->bnx < xb ? o->bx0 + o->bnx : xb, NULL};
    if (h->ba >= h->bb || h->ca >= h->cb) {
        h->ba = h->bb = ya;
        return WF_OK;
    }
    wf_status st = stamp_rows(r, i, h->ba, h->bb, &h->src);
    if (!st) h->src += h->ca - o->bx0;
    return st;
}

/* Adds the active objects that are variable (or, variable 0, the static ones) to rows
 * [y0, y1) of acc, and those in the layer to lacc too when it is not NULL. */
static wf_status add_objects(wf_renderer *r, int y0, int y1, int ncols, int variable, double *acc0, double *lacc)
{
    wf_status st;
    for (size_t a = 0; a < r->nactive; a++) {
        size_t i = r->active[a];
        const wf_render_object *o = &r->objs[i];
        if (!o->variable != !variable) continue;
        int ya = o->y0 > y0 ? o->y0 : y0, yb = o->y0 + o->ny < y1 ? o->y0 + o->ny : y1;
        if (ya >= yb) continue;
        int xa = o->x0 > 0 ? o->x0 : 0, xb = o->x0 + o->nx < ncols ? o->x0 + o->nx : ncols;
        if (o->halo) {
            halo_view h;
            if ((st = halo_open(r, i, ya, yb, xa, xb, &h))) return st;
            for (int y = ya; y < yb; y++) {
                double *acc = acc0 + (size_t)(y - y0) * ncols + xa;
                const float *box = y >= h.ba && y < h.bb ? h.src + (size_t)(y - h.ba) * o->bnx : NULL;
                if ((st = r->cfg.halo(r->draw_ctx, o, y, xa, xb, box, h.ca, h.cb, acc))) return st;
                if (lacc && o->layer &&
                    (st = r->cfg.halo(r->draw_ctx, o, y, xa, xb, box, h.ca, h.cb, lacc + (size_t)(y - y0) * ncols + xa)))
                    return st;
            }
            continue;
        }
        const float *src = NULL;
        if ((st = stamp_rows(r, i, ya, yb, &src))) return st;
        for (int y = ya; y < yb; y++) {
            const float *s = src + (size_t)(y - ya) * o->nx - o->x0;
            double *acc = acc0 + (size_t)(y - y0) * ncols;
            for (int x = xa; x < xb; x++) acc[x] += s[x];
            if (lacc && o->layer) {
                double *la = lacc + (size_t)(y - y0) * ncols;
                for (int x = xa; x < xb; x++) la[x] += s[x];
            }
        }
    }
    return WF_OK;
}

static wf_status fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    wf_renderer *r = ctx;
    if (ncols != r->cfg.ncols || y0 < 0 || y1 > r->cfg.nrows || y1 < y0)
        return wf_error(WF_ERR_INTERNAL, "renderer: asked for rows %d-%d of %d x %d", y0, y1,
                        ncols, r->cfg.nrows);
    if (y0 < r->last_start) { /* went backwards: start the scan again */
        for (size_t a = 0; a < r->nactive; a++) r->stamp_off[r->active[a]] = NO_STAMP;
        r->live_bytes = 0;
        r->nactive = 0;
        r->next = 0;
        r->pool_used = 0;
    }
    r->last_start = y0;
    /* release the boxes the request has passed (a halo object's box ends before its
     * footprint, whose halo is still needed) and the passed rows of the others (they stay
     * where they are until a compaction), retire the objects whose footprint it has
     * passed, then admit those that start before its end */
    size_t keep = 0;
    for (size_t a = 0; a < r->nactive; a++) {
        size_t i = r->active[a];
        const wf_render_object *o = &r->objs[i];
        if (r->stamp_off[i] != NO_STAMP && r->stamp_row0[i] < y0) {
            size_t had = kept_bytes(o, r->stamp_row0[i]);
            if (o->by0 + o->bny <= y0) {
                r->live_bytes -= had;
                r->stamp_off[i] = NO_STAMP;
            } else {
                r->live_bytes -= had - kept_bytes(o, y0);
                r->stamp_off[i] += (size_t)(y0 - r->stamp_row0[i]) * (size_t)o->bnx * sizeof(float);
                r->stamp_row0[i] = y0;
            }
        }
        if (o->y0 + o->ny > y0) r->active[keep++] = i;
    }
    r->nactive = keep;
    while (r->next < r->n && r->objs[r->next].y0 < y1) {
        const wf_render_object *o = &r->objs[r->next];
        if (o->y0 + o->ny > y0) r->active[r->nactive++] = r->next;
        r->next++;
    }
    size_t rows = (size_t)(y1 - y0), npix = rows * (size_t)ncols;
    wf_status st = grow(&r->acc, &r->acc_cap, npix, "row accumulator");
    if (st) return st;
    if ((st = grow(&r->plane, &r->plane_cap, npix, "plane rows"))) return st;
    const int layer = r->cfg.layer != NULL, got = r->cfg.plane_get != NULL;
    if (layer && (st = grow(&r->lplane, &r->lplane_cap, npix, "layer rows"))) return st;
    /* the static objects into the plane (and the layer), from 0.0 as a scene without sky
     * starts, or both from plane_get */
    double *sacc = NULL, *lacc = NULL;
    if (got) {
        if ((st = r->cfg.plane_get(r->cfg.plane_ctx, y0, y1, ncols, r->plane, layer ? r->lplane : NULL))) return st;
    } else {
        if ((st = grow(&r->sacc, &r->sacc_cap, npix, "plane accumulator"))) return st;
        sacc = r->sacc;
        for (size_t k = 0; k < npix; k++) sacc[k] = 0.0;
        if (layer) {
            if ((st = grow(&r->lacc, &r->lacc_cap, npix, "layer accumulator"))) return st;
            lacc = r->lacc;
            for (size_t k = 0; k < npix; k++) lacc[k] = 0.0;
        }
        if ((st = add_objects(r, y0, y1, ncols, 0, sacc, lacc))) return st;
        for (size_t k = 0; k < npix; k++) r->plane[k] = (float)sacc[k];
        if (layer)
            for (size_t k = 0; k < npix; k++) { /* the floor on the float its user sees */
                float f = lacc[k] > 0.0 ? (float)lacc[k] : 0.0f;
                r->lplane[k] = f >= r->cfg.layer_floor ? f : 0.0f;
            }
        if (r->cfg.plane_put)
            for (int y = y0; y < y1; y++) {
                size_t off = (size_t)(y - y0) * ncols;
                r->cfg.plane_put(r->cfg.plane_ctx, y, r->plane + off, layer ? r->lplane + off : NULL, ncols);
            }
    }
    for (int y = y0; y < y1; y++) {
        double *acc = r->acc + (size_t)(y - y0) * ncols;
        if (r->cfg.sky_fn) {
            if ((st = r->cfg.sky_fn(r->cfg.sky_ctx, y, ncols, acc))) return st;
        } else {
            for (int x = 0; x < ncols; x++) acc[x] = r->cfg.sky;
        }
    }
    for (size_t k = 0; k < npix; k++) r->acc[k] += (double)r->plane[k];
    if ((st = add_objects(r, y0, y1, ncols, 1, r->acc, NULL))) return st;
    /* the objects' draws keep their negative ringing (so that none adds flux); the sum,
     * sky included, is clipped here */
    for (size_t k = 0; k < npix; k++) rate[k] = r->acc[k] > 0.0 ? (float)r->acc[k] : 0.0f;
    if (layer)
        for (int y = y0; y < y1; y++)
            r->cfg.layer(r->cfg.layer_ctx, y, r->lplane + (size_t)(y - y0) * ncols, ncols);
    return WF_OK;
}

/* Rows [y0, y1) of the varying objects' slopes, right after fill() for the same rows: the
 * active set is the one fill() left, the stamps are the ones it used. */
static wf_status fill_slope(void *ctx, int y0, int y1, int ncols, float *slope, int *any)
{
    wf_renderer *r = ctx;
    *any = 0;
    if (ncols != r->cfg.ncols || y0 != r->last_start)
        return wf_error(WF_ERR_INTERNAL, "renderer: slopes of rows %d-%d asked without their rates", y0, y1);
    memset(slope, 0, (size_t)(y1 - y0) * (size_t)ncols * sizeof *slope);
    for (size_t a = 0; a < r->nactive; a++) {
        size_t i = r->active[a];
        const wf_render_object *o = &r->objs[i];
        if (o->rel_slope == 0.0) continue;
        int ya = o->y0 > y0 ? o->y0 : y0, yb = o->y0 + o->ny < y1 ? o->y0 + o->ny : y1;
        if (ya >= yb) continue;
        int xa = o->x0 > 0 ? o->x0 : 0, xb = o->x0 + o->nx < ncols ? o->x0 + o->nx : ncols;
        wf_status st;
        if (o->halo) {
            halo_view h;
            if ((st = halo_open(r, i, ya, yb, xa, xb, &h))) return st;
            if ((st = grow(&r->hbuf, &r->hbuf_cap, (size_t)(xb - xa), "halo row"))) return st;
            double *d = r->hbuf;
            for (int y = ya; y < yb; y++) {
                float *dst = slope + (size_t)(y - y0) * ncols + xa;
                const float *box = y >= h.ba && y < h.bb ? h.src + (size_t)(y - h.ba) * o->bnx : NULL;
                memset(d, 0, (size_t)(xb - xa) * sizeof *d);
                if ((st = r->cfg.halo(r->draw_ctx, o, y, xa, xb, box, h.ca, h.cb, d))) return st;
                for (int x = 0; x < xb - xa; x++) dst[x] += (float)(o->rel_slope * d[x]);
            }
            *any = 1;
            continue;
        }
        const float *src = NULL;
        if ((st = stamp_rows(r, i, ya, yb, &src))) return st;
        for (int y = ya; y < yb; y++) {
            const float *sr = src + (size_t)(y - ya) * o->nx - o->x0;
            float *dst = slope + (size_t)(y - y0) * ncols;
            for (int x = xa; x < xb; x++) dst[x] += (float)(o->rel_slope * sr[x]);
        }
        *any = 1;
    }
    return WF_OK;
}

void wf_renderer_source(wf_renderer *r, wf_scene_source *out)
{
    out->ctx = r;
    out->fill_rate = fill;
    out->rows_empty = NULL;
    out->fill_slope = NULL;
    for (size_t i = 0; i < r->n; i++)
        if (r->objs[i].rel_slope != 0.0) {
            out->fill_slope = fill_slope;
            break;
        }
}
