/* The persistence history of one exposure of one SCA (hal/persist.h), built on the host from
 * the earlier exposures themselves, never from their noisy products: for each earlier
 * exposure (a slot, most recent first) the charge its bright objects put in each pixel,
 * rate x exposure time up to the full well, kept where it reaches min_stimulus. The objects
 * are those of the earlier exposure's own scene (its pointing, filter, catalogs, PSF) one pixel
 * of which could reach min_stimulus (wf_persist_peak_fraction, with that PSF's own bound on a
 * point source's brightest pixel), drawn as the scene draws them, without sky (~0.4
 * e-/s: < 400 e- in 900 s) or supernovae. So an item's history is a function of the plan,
 * the configuration and the catalogs: any split of a survey run gives the same bytes (a slot
 * taken from the drawing of its own exposure, wf_persist_layer below, is the same list).
 * Memory: 8 bytes per pixel and slot kept (a saturated star keeps ~100 pixels); a run's
 * cache holds up to 8 exposures' lists per SCA. */
#ifndef WF_TOOLS_PERSIST_H
#define WF_TOOLS_PERSIST_H

#include "hal/persist.h"
#include "hal/scene.h"
#include "sim/draw/scene.h"
#include "sim/survey/catalog.h"
#include "tools/config.h"

typedef struct wf_persist_history wf_persist_history;

wf_status wf_persist_history_new(int ncols, int nrows, double min_stimulus, double full_well,
                                 wf_persist_history **out);
void wf_persist_history_free(wf_persist_history *h);

/* The next slot (older than those added): rate x exptime of every pixel of src, capped at
 * full_well, where it reaches min_stimulus; the exposure ended dt seconds before the reset. */
wf_status wf_persist_history_add_source(wf_persist_history *h, const wf_scene_source *src,
                                        double exptime, double dt);

/* Earlier exposures' kept pixels, by (exposure id, SCA), kept across a survey run's items in
 * one process: per SCA its last WF_PERSIST_DEPTH_MAX exposures, so the next item of an SCA
 * draws only the exposure before it. What it holds is a function of its key and the run's
 * inputs, so using it changes no byte, only the cost. */
typedef struct wf_persist_cache wf_persist_cache;
wf_status wf_persist_cache_new(wf_persist_cache **out);
void wf_persist_cache_free(wf_persist_cache *c);

/* Where the cache stands now; wf_persist_cache_export(c, mark) gives the exposures added since
 * (a child process's drawing, for its parent), as bytes for wf_persist_cache_import (*buf
 * malloc'd, NULL when none). Import keeps the entries it already holds. */
unsigned long wf_persist_cache_mark(const wf_persist_cache *c);
wf_status wf_persist_cache_export(const wf_persist_cache *c, unsigned long mark, void **buf, size_t *size);
wf_status wf_persist_cache_import(wf_persist_cache *c, const void *buf, size_t size);

/* The next slot from the exposure cfg describes (its scene as `wfisim expose` would draw it,
 * bright objects only; the grid scene whole), clock its read pattern; through cache when not
 * NULL (which must outlive h); a scene drawn takes its PSF through psfs when not NULL. When
 * cache does not hold the slot and find (may be NULL) gives that exposure's entry in a scene
 * cache (sim/draw/plane_cache.h), holding the layer its own drawing handed over, the slot is
 * read from the layer's rows instead of drawn (the same list: the layer is exactly the bright
 * objects' rates). *drawn: 1 when it was drawn, 0 when a cache held it. */
struct wf_plane_entry;
/* Looks for an earlier exposure's entry in a scene cache: *out the entry (closed by the
 * caller of this) or NULL. */
typedef wf_status (*wf_persist_plane_fn)(void *ctx, struct wf_plane_entry **out);
wf_status wf_persist_history_add_exposure(wf_persist_history *h, const wf_config *cfg,
                                          const wf_clock *clock, double dt, wf_persist_cache *cache,
                                          wf_scene_psf_cache *psfs, wf_persist_plane_fn find, void *find_ctx,
                                          int *drawn);

/* An exposure's own slot, collected while that exposure is drawn for its product: its bright
 * objects (those wf_persist_history_add_exposure would draw) form the scene's layer
 * (wf_scene_set_layer), whose rows give exactly the pixels and codes a later item's history
 * would draw from them, so a run in plan order draws no history of its own. */
typedef struct wf_persist_layer wf_persist_layer;

/* For the exposure cfg and clock describe; min_stimulus and full_well as the histories'
 * (wf_persist_history_new). */
wf_status wf_persist_layer_new(const wf_config *cfg, const wf_clock *clock, double min_stimulus, double full_well,
                               wf_persist_layer **out);
void wf_persist_layer_free(wf_persist_layer *l);

/* The flags of the catalogs' bright objects at a PSF whose point-source pixel bound is
 * psf_pixel_max (valid while l lives; NULL for an absent catalog). */
wf_status wf_persist_layer_flags(wf_persist_layer *l, const wf_catalog *gal, const wf_catalog *stars,
                                 double psf_pixel_max, const uint8_t **gal_flags, const uint8_t **star_flags);

/* The rate below which no pixel of the layer is kept (min_stimulus / exptime, a hair lower):
 * wf_scene_set_layer's floor. */
double wf_persist_layer_floor(const wf_persist_layer *l);
/* The layer's row callback (wf_scene_set_layer's fn, with l as ctx). */
void wf_persist_layer_row(void *ctx, int y, const float *rates, int ncols);

/* When every row came: the slot into cache as (expid, sca), unless the cache holds it. */
wf_status wf_persist_layer_finish(wf_persist_layer *l, wf_persist_cache *cache, long long expid, int sca);

/* The history as the firmware's source (valid while h lives); depth 0 when no slot kept a pixel. */
void wf_persist_history_source(wf_persist_history *h, wf_persist_source *out);

/* The most of object i's flux (of cat, stars or galaxies) one pixel can hold when drawn with a
 * PSF that puts at most psf_peak of a point source's flux in a pixel (wf_scene_stats'
 * psf_pixel_max): the bound that picks an earlier exposure's bright objects, those whose
 * flux x this reaches min_stimulus. */
double wf_persist_peak_fraction(const wf_catalog *cat, size_t i, double psf_peak);

/* Pixels kept in slot j (for tests and the log). */
size_t wf_persist_history_pixels(const wf_persist_history *h, int slot);

#endif
