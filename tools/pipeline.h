/* One exposure of one SCA from configuration to products: catalogs selected for the SCA's
 * footprint, the scene (or a grid or a replay), the firmware on run.threads threads, the packet
 * stream assembled to FITS in-process (or written out as a stream), and the truth table beside
 * the image. `wfisim expose`, `wfisim demo` and `wfisim survey run` all come through here, so a
 * survey product is byte-identical to the same exposure asked for with `wfisim expose`. */
#ifndef WF_PIPELINE_H
#define WF_PIPELINE_H

#include "hal/clock.h"
#include "hal/persist.h"
#include "hal/scene.h"
#include "sim/survey/catalog.h"
#include "sim/draw/scene.h"
#include "tools/assemble.h"
#include "tools/config.h"
#include "tools/digest.h"
#include "tools/sninject.h"

/* Catalogs of the scene: a synthetic field around the SCA, files, or a GalSim scene. */
typedef struct wf_scene_inputs {
    wf_catalog gal, stars, sne;
    int have_gal, have_stars, have_sne;
    int galsim_scene; /* read as a GalSim benchmark scene (scene.kind galsim, or catalog by its columns) */
} wf_scene_inputs;

/* Reads (or generates) the catalogs of cfg's scene and keeps the rows whose stamps can reach
 * the SCA of cfg's pointing. */
wf_status wf_pipeline_load_catalogs(const wf_config *cfg, wf_scene_inputs *in);
/* The footprint of cfg's SCA (its readout.ncols x nrows pixels) at cfg's pointing, grown by
 * margin_arcsec. */
wf_status wf_pipeline_sca_footprint(const wf_config *cfg, double margin_arcsec, wf_skyregion *reg);

/* The same for any region (a GalSim scene catalog is read whole). */
wf_status wf_pipeline_load_catalogs_in(const wf_config *cfg, const wf_skyregion *reg, wf_scene_inputs *in);
void wf_pipeline_inputs_free(wf_scene_inputs *in);

typedef struct wf_pipeline_job {
    const wf_config *cfg;
    const wf_clock *clock;
    const char *stream;          /* write the packet stream here ("-": stdout) instead of FITS */
    const char *replay;          /* take the rates from this recording */
    const char *meta_extra;      /* further "hdr.KEY = value / comment" lines, or NULL */
    const wf_scene_sn *sne;      /* supernovae to inject as given (NULL or nsne = 0: none) */
    size_t nsne;
    wf_sn_injector *injector;    /* and those of an SN sample on this SCA at cfg's MJD, or NULL */
    const char *version;         /* for the ORIGIN keyword and the version part of the digest */
    wf_digest_cache *digests;    /* file digests kept across a run's products, or NULL */
    const wf_persist_source *persist; /* earlier exposures' charge (tools/persist.h), or NULL: none */
    struct wf_persist_layer *layer;   /* collects this exposure's own persistence slot while it
                                       * is drawn (tools/persist.h), or NULL */
    wf_scene_psf_cache *psfs;    /* PSFs kept from earlier exposures (sim/draw/scene_psf.h), or NULL */
    struct wf_plane_cache *planes; /* static planes kept for the later exposures of a scene
                                    * (sim/draw/plane_cache.h), or NULL */
    /* out */
    char image_path[WF_PATH_MAX + 64];
    char truth_path[WF_PATH_MAX + 64];
    size_t nsne_drawn;           /* SNe that reach the SCA */
    int plane_found;             /* the static plane came from planes */
    int plane_not_kept;          /* it was drawn, and planes could not keep it */
    wf_digest digest;            /* the inputs that shaped it (WFDIGEST and its parts) */
} wf_pipeline_job;

wf_status wf_pipeline_expose(wf_pipeline_job *job);

/* The key of the static plane of job's exposure (sim/draw/plane_cache.h): a digest of every
 * input that shapes the product (tools/digest.h) but its date and exposure id, and of whether
 * the plane carries the persistence layer (layer nonzero). */
wf_status wf_pipeline_plane_key(const wf_pipeline_job *job, int layer, char key[65]);

/* The product names of an exposure and SCA in dir. */
void wf_pipeline_paths(const char *dir, unsigned exposure, unsigned sca, char *image, char *truth,
                       size_t cap);

/* The seconds of light an exposure collects: the single frame's exptime, else the ramp's
 * span from the reset to its last read. */
double wf_pipeline_exptime(const wf_config *cfg, const wf_clock *clock);

/* The scene setup of cfg's exposure (pointing, filter, PSF and drawing knobs) for `threads`
 * renderers. */
void wf_pipeline_scene_setup(const wf_config *cfg, const wf_clock *clock, int threads, wf_scene_setup *ss);

/* The built-in grid scene of cfg (scene.sky_rate, scene.grid.*). */
void wf_pipeline_grid(const wf_config *cfg, wf_scene_grid *g);

/* The assembler's options from cfg: run.out, run.quiet and products.* (compress auto is
 * none here; `survey run` resolves it to rice before it comes through). */
void wf_pipeline_assemble_options(const wf_config *cfg, wf_assemble_options *opt);


#endif
