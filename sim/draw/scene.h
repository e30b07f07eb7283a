/* One SCA's scene for one exposure: what the renderer draws and what the truth records.
 * From a pointing, an SCA, a filter and a date it builds the WCS, the bandpass, the sky (the
 * zodiacal level at that position and date, times 1 + stray light, over each pixel's own
 * area, plus thermal), the PSF of that SCA and filter (only this one; achromatic or for a
 * flat-f_nu SED, with optional jitter and charge diffusion), and one render object
 * per catalog entry whose stamp reaches the SCA, with its flux from the bandpass and its
 * shape carried from the sky frame (u west, v north, GalSim's) into the pixel frame through
 * the local WCS. Each readout thread gets its own renderer and drawing state. */
#ifndef WF_SCENE_BUILD_H
#define WF_SCENE_BUILD_H

#include <stddef.h>
#include <stdint.h>
#include "hal/scene.h"
#include "sim/survey/catalog.h"

/* A supernova to inject: a point source whose AB magnitude in the setup's filter at this
 * exposure the caller has taken from its light curve. A magnitude >= 99 (no flux: before
 * explosion, faded, or outside the model) draws nothing, but the SN stays in the truth. */
typedef struct wf_scene_sn {
    long long id, host_id;  /* host_id -1: hostless */
    double ra, dec;         /* degrees */
    double z;
    double phase;           /* rest-frame days from peak at the exposure mid-time */
    double mag;             /* AB magnitude at mid-exposure (>= 99: no flux) */
    double dlnf_dt;         /* d ln(flux) / dt at mid-exposure, 1/s (0: constant); drawn
                             * up the ramp as a rate linear in time */
    unsigned flags;         /* WF_SALT_* flags of the light-curve evaluation */
} wf_scene_sn;

/* The PSFs of earlier scenes, for the later ones of the same SCA, filter and PSF knobs
 * (sim/draw/scene_psf.h). */
typedef struct wf_scene_psf_cache wf_scene_psf_cache;

typedef struct wf_scene_setup {
    double ra, dec, pa;     /* boresight and observatory position angle, degrees */
    int sca;                /* 1..18 */
    char filter[16];
    double mjd;             /* exposure mid-time (sky, supernova epochs) */
    char data_dir[1024];    /* "" -> built-in pupil, focal plane, bandpass, sky */
    int ncols, nrows;       /* active pixels simulated [4088] */
    int pupil_bin;          /* [8] */
    int psf_oversample;     /* PSF image sampling 0.11/K arcsec [4] */
    int psf_size;           /* PSF image side in samples [256] */
    int psf_nlambda;        /* 1: achromatic at the band's effective wavelength; n > 1:
                             * chromatic, a flat-f_nu source over n slices of the band [1] */
    double jitter;          /* pointing jitter, Gaussian sigma per axis, arcsec [0: off] */
    double diffusion;       /* charge diffusion, Gaussian sigma per axis, pixels [0: off] */
    double flux_fraction;   /* stamps hold at least this [0.995] */
    double core_radius;     /* arcsec, the PSF's core and wing split (sim/draw/profile.h); 0: none [2] */
    int core_levels;        /* core radii core_radius, halved at each level (sim/draw/profile.h) [3] */
    double noise_tolerance; /* per object, looser knobs whose error bound stays below this x
                             * the sky noise of one pixel over exptime: folding (in [the
                             * profile default, WF_SCENE_FOLD_MAX]), the Fourier cut (up to
                             * WF_SCENE_KVALUE_MAX), the knot lattice's accuracy (up to
                             * WF_SCENE_KNOT_MAX), knots drawn as the smooth disk (when the
                             * knots' flux x the PSF's pixel_max is below it) and the split
                             * PSF's wing; 0: the same knobs for all [1]. The sky noise is
                             * at the least sky the pointing has on any date (stats.sky_least),
                             * so the knobs do not depend on mjd */
    double exptime;         /* s, for noise_tolerance [300] */
    size_t pool_bytes;      /* stamp pool per renderer (float stamps) [24 MiB] */
    int threads;            /* renderers to prepare [1] */
    int sky_on;             /* add the sky [1] */
    int sky_noise;          /* noise_tolerance's scale is the exposure's sky noise even when
                             * sky_on is 0 (a persistence history: its exposure had the sky,
                             * its stimulus is the objects' charge alone) [0] */
    double stray_light;     /* zodiacal light x (1 + this) [0.1, SPEC 2 / GalSim] */
    double bright_mag;      /* point sources brighter than this AB magnitude are drawn with a
                             * wide PSF (4x the image side, pupil_bin 4 or finer: the halo and
                             * diffraction spikes to ~14"), built only when one is present
                             * [15; below -50: never] */
    const wf_scene_sn *sne; /* supernovae (must outlive the scene) [none] */
    size_t nsne;
    wf_scene_psf_cache *psf_cache; /* take the PSF from here and keep it there
                                    * (sim/draw/scene_psf.h; must outlive the scene)
                                    * [NULL: the scene's own] */
} wf_scene_setup;

#define WF_SCENE_FOLD_MAX 0.05    /* noise_tolerance: folding at most this */
#define WF_SCENE_KVALUE_MAX 1e-3  /* and the Fourier cut at most this (docs/ACCURACY.md) */
#define WF_SCENE_KNOT_MAX 1e-2    /* and the knot lattice's accuracy at most this */
#define WF_SCENE_KNOT_BOUND 10.0  /* a pixel moves by at most this x knot_accuracy x the knots'
                                     flux (sim/draw/profile_lattice.c) */

typedef struct wf_scene_stats {
    long galaxies, stars, sne; /* drawn (reach the SCA) */
    long split;                /* of the galaxies, drawn with the split PSF (noise_tolerance) */
    double sky_min, sky_max;   /* e-/pixel/s over the SCA */
    double sky_least;          /* e-/pixel/s: the least over the SCA at the least zodiacal light
                                  of its centre within the field of regard (any date,
                                  wf_sky_zodiacal_least): noise_tolerance's scale */
    double zodi;               /* e-/s/arcsec^2 at the SCA centre */
    double psf_lambda_nm;
    double psf_image_sum;      /* the PSF image's share of the light before normalising */
    double psf_pixel_max;      /* no pixel of a point source (the PSF, pixel included) holds
                                  more than this of its flux, wherever it sits (psf.pixel_max
                                  of sim/draw/profile.h); known after wf_scene_prepare */
    long bright;               /* point sources drawn with the wide PSF */
    long knots_smooth;         /* galaxies whose knots are drawn as the smooth disk
                                  (noise_tolerance) */
    double wide_psf_seconds;   /* building it (0: not built) */
    double build_seconds;
} wf_scene_stats;

typedef struct wf_scene wf_scene;

void wf_scene_setup_default(wf_scene_setup *s);

/* gal and stars may be NULL; they must outlive the scene. Magnitudes come from the column
 * of the setup's filter. */
wf_status wf_scene_create(const wf_scene_setup *setup, const wf_catalog *gal,
                          const wf_catalog *stars, wf_scene **out);

/* wf_scene_create in two steps, so that the catalogs can be read while the optics are built:
 * prepare does everything that needs no object (WCS, bandpass, sky, the PSF and its tables;
 * setup->sne is not read), populate adds the objects and makes the renderers. The same
 * scene, bit for bit. populate once per prepared scene; after either fails, only
 * wf_scene_destroy. */
wf_status wf_scene_prepare(const wf_scene_setup *setup, wf_scene **out);
wf_status wf_scene_populate(wf_scene *scene, const wf_catalog *gal, const wf_catalog *stars,
                            const wf_scene_sn *sne, size_t nsne);

/* Between prepare and populate: the catalog rows flagged nonzero (gal_flags[i] for row i of
 * the galaxies populate gets, star_flags for the stars; either may be NULL: none) form the
 * renderers' layer (sim/draw/render.h): every row the scene's sources fill is also summed
 * over those objects alone, without sky, and handed to fn(ctx, y, rates, ncols), exactly the
 * rates of a scene populated with those objects alone and the sky off (sky_noise set when
 * this one has a sky), but that rates below floor come as 0 (fn must ignore them: a plane
 * cache then keeps only the rows that matter). The flags must outlive populate. */
void wf_scene_set_layer(wf_scene *scene, const uint8_t *gal_flags, const uint8_t *star_flags,
                        void (*fn)(void *ctx, int y, const float *rates, int ncols), void *ctx, double floor);
/* Between prepare and populate: the static plane (sim/draw/render.h) through entry
 * (sim/draw/plane_cache.h), which the scene then owns (closed with it, which keeps what it
 * wrote). found: the plane comes from the entry, and populate neither plans nor draws the
 * galaxies and stars (its counts come from the entry's note; wf_scene_object_count and
 * wf_scene_draw_object then see the supernovae alone); else the scene hands its plane to the
 * entry. The rates are the same bits either way when the entry's key covers everything
 * but the date that shapes the scene. */
struct wf_plane_entry;
void wf_scene_set_plane(wf_scene *scene, struct wf_plane_entry *entry, int found);
void wf_scene_destroy(wf_scene *scene);

/* Scene source for readout thread t (0 <= t < setup.threads). */
wf_status wf_scene_source_for(wf_scene *scene, int t, wf_scene_source *out);

void wf_scene_get_stats(const wf_scene *scene, wf_scene_stats *out);

/* The stamp of drawn object k (0 <= k < count): bounds in SCA pixels (0-based) and pixels in
 * e-/s, as the renderer adds them (negative ringing left in: the renderer clips the sum of
 * all objects and the sky); *pix is malloc'd for the caller. Also its catalog id,
 * kind (0 galaxy, 1 star, 2 supernova), position (0-based pixels), magnitude and flux. */
typedef struct wf_scene_object {
    long long id;
    int kind;
    double x, y, ra, dec, mag, flux;
} wf_scene_object;
size_t wf_scene_object_count(const wf_scene *scene);
wf_status wf_scene_draw_object(wf_scene *scene, size_t k, wf_scene_object *info, int *x0, int *y0,
                               int *nx, int *ny, double **pix);

/* 1 when some drawn object's brightness changes over the exposure (the readout must then
 * follow the sources' fill_slope: wf_readout_config.time_variable). */
int wf_scene_time_variable(const wf_scene *scene);

/* Renderer totals over all threads: stamps drawn whole and in pieces, pool high water. */
void wf_scene_render_stats(const wf_scene *scene, long *stamps, long *pieces, size_t *pool_high);

/* Writes the truth of what was drawn: tables GALAXIES, STARS and SNE with ID, RA, DEC, X, Y
 * (FITS 1-based pixel centres), MAG (this filter), FLUX (e-/s); SNE also Z, HOSTID, PHASE
 * (rest-frame days from peak) and FLAGS. Objects whose centre is on the SCA are listed.
 * digest, when not NULL, goes into the primary header as WFDIGEST: the inputs of the image
 * it belongs to (tools/digest.h), so the pair can be matched. Through a temporary file. */
wf_status wf_scene_write_truth(const wf_scene *scene, const char *path, const char *digest);

/* The pointing's WCS header cards, for the image HDUs: "KEY = value" lines as META hdr.
 * lines would carry them (written into buf, NUL-terminated). */
wf_status wf_scene_wcs_meta(const wf_scene *scene, char *buf, size_t cap);

#endif
