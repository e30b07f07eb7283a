/* A scene's PSF: the image of one SCA and filter under the PSF knobs (pupil binning, image
 * side and sampling, wavelengths, jitter, diffusion, data files) and the drawer's tables of
 * it (sim/draw/profile.h), with the wide PSF of bright point sources built when first asked
 * for. None of it depends on an exposure's pointing, date or objects, so the items of a survey
 * that share an SCA and a filter can share it: a cache keeps the last few for the scenes that
 * follow, the same bits as building them again (the same code on the same inputs; the tables
 * are the same for any thread count). ~30 MiB each at the defaults (the wide PSF 4 MiB more).
 * Not thread-safe: a process's scenes take and give back PSFs one after another. */
#ifndef WF_SCENE_PSF_H
#define WF_SCENE_PSF_H

#include "sim/draw/profile.h"
#include "sim/draw/scene.h"

typedef struct wf_scene_psf {
    wf_profile_psf ppsf;          /* the tables (pointers into the PSF's own memory) */
    double image_sum;             /* the image's share of the light before normalising */
    double lambda_nm;             /* photon-weighted mean wavelength of the slices */
    int wide_built;               /* wf_scene_psf_wide has run */
    wf_profile_psf ppsf_wide;
    double wide_seconds;          /* building the wide PSF */
    struct wf_scene_psf_private *priv;
} wf_scene_psf;

/* The drawing knobs of a scene of setup before any object's own (wf_profile_accuracy's
 * defaults with setup's flux_fraction and core split): the PSF's tables are made under them,
 * and the scene's works too. */
void wf_scene_psf_accuracy(const wf_scene_setup *setup, wf_profile_accuracy *acc);

/* Keeps up to `capacity` (>= 1) PSFs; the least recently taken goes first. */
wf_status wf_scene_psf_cache_new(int capacity, wf_scene_psf_cache **out);
/* Frees the PSFs no scene holds; those still held go with their last wf_scene_psf_release. */
void wf_scene_psf_cache_free(wf_scene_psf_cache *c);

typedef struct wf_scene_psf_cache_stats {
    long built, reused;           /* wf_scene_psf_get calls that built, that found it kept */
    long wide_built;              /* wide PSFs built */
} wf_scene_psf_cache_stats;
void wf_scene_psf_cache_get_stats(const wf_scene_psf_cache *c, wf_scene_psf_cache_stats *out);

/* The PSF of setup's SCA, filter and PSF knobs: the cache's when it holds one of that key,
 * else built (and kept there; cache NULL: the caller's alone), on up to setup->threads
 * threads. Held until wf_scene_psf_release. */
wf_status wf_scene_psf_get(wf_scene_psf_cache *cache, const wf_scene_setup *setup, wf_scene_psf **out);
/* Builds p's wide PSF unless it has one. */
wf_status wf_scene_psf_wide(wf_scene_psf *p);
void wf_scene_psf_release(wf_scene_psf *p);

/* Builds the PSF of setup (and with wide its wide PSF) into setup->psf_cache unless it holds
 * them: for a process that forks the makers of its scenes, so that each child finds them
 * (a child's own build is lost with it). */
wf_status wf_scene_psf_prefetch(const wf_scene_setup *setup, int wide);

#endif
