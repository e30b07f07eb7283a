/* Tile renderer: the scene source behind the firmware (hal/scene.h) when the scene is a list
 * of objects. Objects are sorted by their first row; an object's stamp is drawn once, when
 * the first tile that touches it asks, its rows are added to every tile it overlaps, and it
 * is dropped once the tiles have passed it. Stamps live in a pool of fixed size, compacted
 * once it holds twice the live stamps (so that only about that much of it is ever resident),
 * keeping only the rows the tiles have not yet passed;
 * an object whose stamp does not fit is drawn in pieces (the rows a tile needs), never dropped.
 * Objects entirely off the SCA are never drawn. Stamps are drawn in double and kept in the
 * pool as float. An object may keep only a box of its footprint in the pool and have the
 * rest of its light (over the whole footprint) added row by row by a halo function: a PSF
 * wing that is cheap to recompute costs no pool.
 *
 * The rate of a pixel is sky + plane + the variable objects, then clipped at zero (objects
 * may hand over negative pixels: a draw's ringing kept, so that no object gains flux by its
 * clipping). The plane is the static objects (all but the variable ones) summed from 0.0
 * in double in (first row, id) order and rounded to float once; the variable objects are
 * added to sky + plane in double in the same order. None of it depends on how the rows are
 * split into tiles. The plane is all an exposure needs of its static objects, so it can be
 * handed over (plane_put) and given back to a later renderer of the same static scene
 * (plane_get), which then draws none of them: the same rates, bit for bit. */
#ifndef WF_RENDER_H
#define WF_RENDER_H

#include <stddef.h>
#include <stdint.h>
#include "hal/scene.h"

typedef struct wf_render_object {
    uint64_t id;
    int x0, y0, nx, ny; /* stamp footprint in SCA pixels (0-based), may reach past the edges */
    const void *data;   /* the drawing function's description of the object */
    double rel_slope;   /* d ln(brightness) / dt at the exposure mid-time, 1/s (0: constant;
                         * a supernova): feeds the source's fill_slope (hal/scene.h) */
    int halo;           /* nonzero: the config's halo function adds light over the footprint
                         * (the value is the caller's, e.g. which halo) */
    int bx0, by0, bnx, bny; /* the drawn and kept box, within the footprint (bnx 0: all) */
    int layer;          /* nonzero: also in the layer (wf_renderer_config.layer); static only */
    int variable;       /* nonzero: not in the plane (drawn by every exposure: a supernova);
                         * implied by a nonzero rel_slope */
} wf_render_object;

/* Draws rows [ya, yb) (absolute SCA rows inside the box) of the object's box, in e-/s per
 * pixel, into out[(y - ya) * bnx + i] for columns bx0 + i. A row must come out the same
 * whether it is drawn with the whole box or in a piece. */
typedef wf_status (*wf_draw_fn)(void *ctx, const wf_render_object *obj, int ya, int yb,
                                double *out);

/* Sky rate of row y, written into out[ncols]: lets the sky follow the pixel area. NULL
 * sky function: constant `sky` e-/pixel/s. */
typedef wf_status (*wf_sky_fn)(void *ctx, int y, int ncols, double *out);

/* Adds a halo object's light of row y, columns [xa, xb) (within its footprint and the SCA),
 * into acc[x - xa]: per pixel the box's value (box[x - ca] for x in [ca, cb); box NULL: the
 * row has no box pixels) plus the halo (the sum is clipped at zero with the rest, so
 * negatives may be left in). Called with the draw function's ctx. */
typedef wf_status (*wf_halo_fn)(void *ctx, const wf_render_object *obj, int y, int xa, int xb,
                                const float *box, int ca, int cb, double *acc);

typedef struct wf_renderer_config {
    int ncols, nrows;
    double sky;             /* e-/pixel/s when sky_fn is NULL */
    wf_sky_fn sky_fn;
    void *sky_ctx;
    size_t pool_bytes;      /* stamp pool; a stamp larger than it is drawn in pieces */
    size_t max_row_bytes;   /* piece buffer: the most rows x width a piece may hold [pool/4] */
    wf_halo_fn halo;        /* for objects with halo set [NULL: none may] */
    /* The layer: when set, every row the source fills is also summed over the objects with
     * `layer` alone, without sky, in the same order and clipped at zero the same way (the
     * rates a scene of those objects alone, without sky, would give, bit for bit), and
     * handed to layer(layer_ctx, y, rates, ncols). Rows in more than one request (tile
     * halos) come more than once, the same each time; calls come from every thread that
     * reads a renderer of the scene. [NULL] */
    void (*layer)(void *ctx, int y, const float *rates, int ncols);
    void *layer_ctx;
    /* The plane (above) from elsewhere: plane_get gives rows [y0, y1) of the plane, and of
     * the layer's rates when layer is set (layer non-NULL), as a renderer of the same static
     * objects handed them to plane_put; static objects are then never drawn. [NULL] */
    wf_status (*plane_get)(void *ctx, int y0, int y1, int ncols, float *plane, float *layer);
    /* Every row filled (halo rows more than once, the same each time) with its plane row and
     * the layer's (NULL without a layer), from every thread reading a renderer of the scene.
     * [NULL] */
    void (*plane_put)(void *ctx, int y, const float *plane, const float *layer, int ncols);
    void *plane_ctx;
    /* The layer's rates below this are handed over as 0 (to layer and plane_put alike), for a
     * layer whose user ignores them: the rows of a plane cache then stay holes [0: none] */
    double layer_floor;
} wf_renderer_config;

typedef struct wf_renderer_stats {
    long stamps_drawn;      /* whole stamps drawn */
    long pieces_drawn;      /* partial draws of stamps too large for the pool */
    long objects_kept;      /* objects on (or reaching onto) the SCA */
    long objects_skipped;   /* objects entirely off the SCA */
    size_t pool_high_water; /* most pool bytes in use */
    size_t live_high_water; /* most bytes of stamps still needed at once (<= the above) */
} wf_renderer_stats;

typedef struct wf_renderer wf_renderer;

/* Copies the object list (the `data` pointers must outlive the renderer). */
wf_status wf_renderer_create(const wf_renderer_config *cfg, const wf_render_object *objs,
                             size_t n, wf_draw_fn draw, void *draw_ctx, wf_renderer **out);
void wf_renderer_destroy(wf_renderer *r);

/* The HAL scene source reading this renderer (one renderer per readout thread). It has a
 * fill_slope (the objects' rel_slope times their stamps) when any object varies. */
void wf_renderer_source(wf_renderer *r, wf_scene_source *out);

void wf_renderer_get_stats(const wf_renderer *r, wf_renderer_stats *out);

#endif
