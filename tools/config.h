/* Run configuration: YAML files (libyaml) in the spirit of GalSim's configs, plus
 * `--set key=value` overrides. One table of keys (tools/config.c) drives parsing, range
 * checks, --set and the generated docs/CONFIG.md, so the three cannot disagree.
 * Keys are dotted paths into nested mappings ("detector.gain" is `detector: {gain: 1.0}`).
 * An unknown key, a wrong type or an out-of-range value is an error naming the file, line
 * and key (or "--set" for command-line overrides). */
#ifndef WF_CONFIG_H
#define WF_CONFIG_H

#include <stdio.h>
#include "firmware/readout.h"
#include "hal/clock.h"
#include "hal/file.h"
#include "sim/survey/survey.h"
#include "sim/survey/synth.h"

/* products.compress: `auto` is rice for `survey run`, none for every other command */
enum { WF_COMPRESS_AUTO = 0, WF_COMPRESS_NONE = 1, WF_COMPRESS_RICE = 2 };

typedef struct wf_config {
    uint64_t seed;                 /* seed [1] */
    wf_readout_config ro;          /* readout.*, detector.*, exposure.id/sca/mode/sampling/exptime */
    double frame_time;             /* readout.frame_time [3.16247] */
    char ma_table[WF_PATH_MAX];    /* readout.ma_table: "4", "6", "11" or a file [6] */
    int threads;                   /* run.threads [1] */
    int quiet;                     /* run.quiet [false] */
    int uncached_writes;           /* run.uncached_writes [true] */
    char out_dir[WF_PATH_MAX];     /* run.out ["out"] */
    char scene_cache[WF_PATH_MAX]; /* run.scene_cache: a folder, "auto" or "none" [auto] */
    double scene_cache_gib;        /* run.scene_cache_gib [8] */
    struct {                       /* products.*: what a product keeps (docs/SURVEY.md) */
        int compress;              /* WF_COMPRESS_* [auto] */
        double quantize_level;     /* float HDUs' step is noise / this; 0 lossless [16] */
        int drop_resultants;       /* products.resultants: keep (0) or drop (1) [keep] */
        int border;                /* products.border: write the reference border [false] */
    } products;
    struct {                       /* detector.persistence.*: the history survey run builds */
        double window;             /* s [3600] */
        int depth;                 /* earlier exposures at most [8] */
        double min_stimulus;       /* e- [5000] */
    } persist;
    char filter[16];               /* exposure.filter [Y106] */
    /* Built-in grid scene (scene.*) until the renderer lands. */
    double sky_rate;               /* scene.sky_rate, e-/pixel/s */
    double grid_flux;              /* scene.grid.flux, e-/s per source */
    double grid_sigma;             /* scene.grid.sigma, pixels */
    int grid_spacing;              /* scene.grid.spacing, pixels */
    /* Pointing and scene (pointing.*, scene.*, psf.*) */
    double ra, dec, pa;            /* pointing.ra/dec/pa, degrees [71, -53, 30] */
    double mjd;                    /* exposure.mjd, exposure mid-time [61420] */
    int scene_kind;                /* scene.kind: 0 synthetic, 1 catalog, 2 grid, 3 galsim [synthetic] */
    char catalog[WF_PATH_MAX];     /* scene.catalog: galaxies (FITS/CSV), or a GalSim scene CSV */
    char stars[WF_PATH_MAX];       /* scene.stars: stars (FITS/CSV) */
    int pupil_bin;                 /* psf.pupil_bin [8] */
    int psf_oversample;            /* psf.oversample [4] */
    int psf_nlambda;               /* psf.nlambda [1: achromatic] */
    double psf_jitter;             /* psf.jitter, arcsec [0] */
    double psf_diffusion;          /* psf.diffusion, pixels [0] */
    double psf_bright_mag;         /* psf.bright_mag [15] */
    double flux_fraction;          /* scene.flux_fraction [0.995] */
    double psf_core_radius;        /* psf.core_radius [2] */
    int psf_core_levels;           /* psf.core_levels [3] */
    double noise_tolerance;        /* scene.noise_tolerance [1] */
    int sky_on;                    /* scene.sky [true] */
    double stray_light;            /* scene.stray_light [0.1] */
    double stamp_pool_mib;         /* scene.stamp_pool [32] */
    struct {                       /* scene.synthetic.*: the synthetic field's faint ends */
        double h_faint;            /* galaxies to this H158 [26] */
        double star_density;       /* stars per arcmin^2 with 12 <= V <= star_v_faint... [2.5] */
        double star_v_faint;       /* ...over 12 <= V <= 27, extended at the same counts [27] */
    } synth;
    char data_dir[WF_PATH_MAX];    /* paths.data [$WFISIM_DATA or ""] */
    char reference_dir[WF_PATH_MAX]; /* paths.reference [$WFISIM_REFERENCE or ""] */
    wf_survey_params survey;       /* survey.* (sim/survey/survey.h keeps their table) */
    struct {                       /* sn.*: supernova generation (docs/SUPERNOVAE.md) */
        char model[WF_PATH_MAX];   /* SALT model directory ["": data/salt3/salt3-k21] */
        double h0, om;             /* flat LCDM [70, 0.315] */
        char rate[512];            /* POWERLAW2 pieces separated by ';' */
        double zmin, zmax;         /* [0.06, 2.99] */
        double alpha, beta, sigma_int;
        double x1[5], c[5];        /* peak, sigma-, sigma+, min, max */
        char dztol[128];           /* "a0,a1,a2" */
        double fmax;
        int hostless;
    } sn;
} wf_config;

/* Every key at its documented default (SPEC values). */
void wf_config_defaults(wf_config *cfg);

/* The synthetic field's settings for cfg (its seed and scene.synthetic.*), the one place the
 * renderer, `sn generate`'s hosts and `wfisim catalog` take them from, so all three draw
 * the same field. */
wf_status wf_config_synth(const wf_config *cfg, wf_synth_config *sc);

/* Applies a YAML file on top of cfg; on any error cfg is left as it was. */
wf_status wf_config_load(wf_config *cfg, const char *path);

/* Applies one "key=value" override; origin names where it came from in messages (NULL:
 * "--set"). On any error cfg is left as it was. */
wf_status wf_config_set(wf_config *cfg, const char *assignment, const char *origin);

/* Resolves derived values: the MA table and frame time into clock, seed into cfg->ro;
 * clamps readout.tile_rows to readout.nrows and checks cross-key constraints. */
wf_status wf_config_finish(wf_config *cfg, wf_clock *clock);

/* A directory named by `what` (an option or key, for the message): NULL or "" is none;
 * anything else must be an existing directory, whether or not the run reads from it
 * (WF_ERR_INPUT for a file, WF_ERR_IO when it cannot be found). */
wf_status wf_config_check_dir(const char *what, const char *path);

/* The configuration as it shapes a product's bits, for its input digest (tools/digest.h):
 * "key = value\n" in table order for every key but those that cannot change a product
 * (run.*, readout.tile_rows, readout.compress, paths.reference), those naming a file whose
 * content is digested instead (paths.data, scene.catalog, scene.stars, readout.ma_table, the
 * sn.* keys of the SN sample) and seed (a part of its own); numbers in the shortest text that
 * reads back exactly. *text is malloc'd. */
wf_status wf_config_product_text(const wf_config *cfg, char **text);

/* Writes the Markdown reference of every key (docs/CONFIG.md is this output). */
void wf_config_write_doc(FILE *out);

#endif
