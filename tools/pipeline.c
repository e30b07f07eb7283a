#include "tools/pipeline.h"

#include "sim/draw/plane_cache.h"
#include "tools/persist.h"

#include <errno.h>
#include <fftw3.h>
#include <fitsio.h>
#include <gnu/libc-version.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hal/file.h"
#include "hal/link.h"
#include "hal/scene.h"
#include "sim/survey/skyindex.h"
#include "sim/survey/synth.h"
#include "sim/survey/wcs.h"
#include "tools/assemble.h"
#include "tools/expose.h"

void wf_pipeline_paths(const char *dir, unsigned exposure, unsigned sca, char *image, char *truth,
                       size_t cap)
{
    snprintf(image, cap, "%s/wfisim_e%06u_sca%02u.fits", dir, exposure, sca);
    snprintf(truth, cap, "%s/wfisim_e%06u_sca%02u_truth.fits", dir, exposure, sca);
}

void wf_pipeline_grid(const wf_config *cfg, wf_scene_grid *g)
{
    g->ncols = cfg->ro.ncols;
    g->nrows = cfg->ro.nrows;
    g->sky = cfg->sky_rate;
    g->flux = cfg->grid_flux;
    g->sigma = cfg->grid_sigma;
    g->spacing = cfg->grid_spacing;
}

void wf_pipeline_inputs_free(wf_scene_inputs *in)
{
    if (in->have_gal) wf_catalog_free(&in->gal);
    if (in->have_stars) wf_catalog_free(&in->stars);
    if (in->have_sne) wf_catalog_free(&in->sne);
    memset(in, 0, sizeof *in);
}

wf_status wf_pipeline_sca_footprint(const wf_config *cfg, double margin_arcsec, wf_skyregion *reg)
{
    wf_focal_plane fp;
    wf_wcs w;
    wf_status st;
    if ((st = wf_wcs_focal_plane(cfg->data_dir[0] ? cfg->data_dir : NULL, &fp)) ||
        (st = wf_wcs_for_sca(&fp, cfg->ra, cfg->dec, cfg->pa, (int)cfg->ro.sca, &w)))
        return st;
    double ra[4], dec[4];
    const double cx[4] = {-0.5, cfg->ro.ncols - 0.5, cfg->ro.ncols - 0.5, -0.5};
    const double cy[4] = {-0.5, -0.5, cfg->ro.nrows - 0.5, cfg->ro.nrows - 0.5};
    for (int k = 0; k < 4; k++)
        if ((st = wf_wcs_pix2world(&w, cx[k], cy[k], &ra[k], &dec[k]))) return st;
    return wf_skyindex_polygon(ra, dec, 4, margin_arcsec, reg);
}

/* The SCA's footprint on the sky, widened by the largest stamp reach (70"), so that objects
 * just off the SCA whose light reaches onto it are kept. */
static wf_status sca_region(const wf_config *cfg, wf_skyregion *reg)
{
    return wf_pipeline_sca_footprint(cfg, 70.0, reg);
}

/* Keeps the rows of a catalog read from a file that fall in the footprint (a sky index:
 * milliseconds for millions of rows). */
static wf_status select_rows(wf_catalog *cat, const wf_skyregion *reg)
{
    wf_skyindex *ix;
    wf_selection sel = {0};
    wf_catalog sub;
    wf_status st = wf_skyindex_build(cat->ra, cat->dec, cat->n, 1.0, &ix);
    if (st) return st;
    st = wf_skyindex_select(ix, reg, &sel);
    if (!st) st = wf_catalog_subset(cat, sel.idx, sel.n, &sub);
    wf_skyindex_selection_free(&sel);
    wf_skyindex_free(ix);
    if (st) return st;
    wf_catalog_free(cat);
    *cat = sub;
    return WF_OK;
}

wf_status wf_pipeline_load_catalogs(const wf_config *cfg, wf_scene_inputs *in)
{
    memset(in, 0, sizeof *in);
    wf_skyregion reg;
    wf_status st = sca_region(cfg, &reg);
    return st ? st : wf_pipeline_load_catalogs_in(cfg, &reg, in);
}

wf_status wf_pipeline_load_catalogs_in(const wf_config *cfg, const wf_skyregion *region, wf_scene_inputs *in)
{
    memset(in, 0, sizeof *in);
    wf_skyregion reg = *region;
    wf_status st;
    if (cfg->scene_kind == 0) { /* synthetic: only the cells the SCA (and stamps reaching it) see */
        wf_synth_config sc;
        wf_synth *syn;
        if ((st = wf_config_synth(cfg, &sc)) || (st = wf_synth_create(&sc, &syn))) return st;
        st = wf_synth_select(syn, &reg, &in->gal, &in->stars);
        wf_synth_free(syn);
        if (!st) in->have_gal = in->have_stars = 1;
        return st;
    }
    /* scene.kind catalog takes a GalSim benchmark scene too, recognised by its columns, and
     * then reads it as scene.kind galsim does */
    wf_catalog_format fmt = WF_CATALOG_FORMAT_SCENE;
    if (cfg->scene_kind == 1 && cfg->catalog[0] &&
        (st = wf_catalog_sniff(cfg->catalog, WF_CATALOG_FORMAT_GALAXIES | WF_CATALOG_FORMAT_SCENE, &fmt)))
        return st;
    if (cfg->scene_kind == 3 || (cfg->catalog[0] && fmt == WF_CATALOG_FORMAT_SCENE)) {
        if (!cfg->catalog[0]) return wf_error(WF_ERR_INPUT, "scene.kind galsim needs scene.catalog");
        if (cfg->scene_kind == 1 && cfg->stars[0])
            return wf_error(WF_ERR_INPUT, "%s is a GalSim benchmark scene, which holds its own stars: "
                            "scene.stars (%s) is not read with it", cfg->catalog, cfg->stars);
        st = wf_catalog_read_galsim_scene(cfg->catalog, &in->gal, &in->stars, &in->sne);
        if (!st) in->have_gal = in->have_stars = in->have_sne = in->galsim_scene = 1;
        return st;
    }
    if (!cfg->catalog[0] && !cfg->stars[0])
        return wf_error(WF_ERR_INPUT, "scene.kind catalog needs scene.catalog and/or scene.stars");
    if (cfg->catalog[0]) {
        if ((st = wf_catalog_read_galaxies(cfg->catalog, &in->gal))) return st;
        in->have_gal = 1;
        if ((st = select_rows(&in->gal, &reg))) return st;
    }
    if (cfg->stars[0]) {
        if ((st = wf_catalog_read_stars(cfg->stars, &in->stars))) return st;
        in->have_stars = 1;
        if ((st = select_rows(&in->stars, &reg))) return st;
    }
    return WF_OK;
}

typedef struct assembler_thread {
    wf_link_pipe *in;
    wf_assemble_options opt;
    wf_status status;
    char message[1024];
    char path[WF_PATH_MAX];
} assembler_thread;

void wf_pipeline_assemble_options(const wf_config *cfg, wf_assemble_options *opt)
{
    memset(opt, 0, sizeof *opt);
    opt->out_dir = cfg->out_dir;
    opt->quiet = cfg->quiet;
    opt->compress = cfg->products.compress == WF_COMPRESS_RICE;
    opt->quantize_level = cfg->products.quantize_level;
    opt->drop_resultants = cfg->products.drop_resultants;
    opt->border = cfg->products.border;
}

static long pipe_read(void *ctx, void *buf, size_t n) { return (long)wf_link_pipe_read(ctx, buf, n); }

static void *assemble_main(void *arg)
{
    assembler_thread *a = arg;
    a->status = wf_assemble_source(pipe_read, a->in, "in-process stream", &a->opt, a->path, sizeof a->path);
    if (a->status) snprintf(a->message, sizeof a->message, "%s", wf_error_message());
    /* a readout still sending after a failure stops at its next packet, not blocked on a
     * full pipe */
    wf_link_pipe_close_read(a->in);
    return NULL;
}

/* The job's supernovae and those of a GalSim scene catalog (point sources of fixed
 * magnitude, no light curve) as one list for the scene. */
static wf_status gather_sne(const wf_pipeline_job *pj, const wf_scene_inputs *in, wf_scene_sn **out,
                            size_t *n)
{
    size_t ncat = in->have_sne ? in->sne.n : 0, ninj = 0;
    wf_scene_sn *inj = NULL;
    *out = NULL;
    *n = 0;
    if (pj->injector) {
        wf_skyregion reg;
        wf_status st = sca_region(pj->cfg, &reg);
        if (!st) st = wf_sn_injector_select(pj->injector, pj->cfg->filter, pj->cfg->mjd, &reg, &inj, &ninj);
        if (st) return st;
    }
    size_t total = pj->nsne + ncat + ninj;
    if (!total) { free(inj); return WF_OK; }
    wf_scene_sn *v = calloc(total, sizeof *v);
    if (!v) { free(inj); return wf_error(WF_ERR_NOMEM, "out of memory for %zu supernovae", total); }
    if (pj->nsne) memcpy(v, pj->sne, pj->nsne * sizeof *v);
    if (ninj) memcpy(v + pj->nsne + ncat, inj, ninj * sizeof *v);
    free(inj);
    if (ncat) {
        int band;
        wf_status st = wf_catalog_band(&in->sne, pj->cfg->filter, &band);
        if (st) { free(v); return st; }
        for (size_t i = 0; i < ncat; i++) {
            wf_scene_sn *sn = &v[pj->nsne + i];
            sn->id = in->sne.id[i];
            sn->host_id = -1;
            sn->ra = in->sne.ra[i];
            sn->dec = in->sne.dec[i];
            sn->z = NAN;
            sn->phase = NAN;
            sn->mag = in->sne.mag[band][i];
        }
    }
    *out = v;
    *n = total;
    return WF_OK;
}

/* Where `--stream FILE` goes. A file is written as FILE.tmp and renamed once the whole
 * stream is out, removed on failure, as every product is: a full disk or a failed readout
 * never leaves a truncated stream under FILE (an old FILE stays as it was). Standard output
 * ("-") and what is not a regular file (a pipe, a FIFO, a character device) take the bytes
 * as they come: they cannot be renamed. */
typedef struct stream_out {
    FILE *file;
    const char *path;
    char tmp[WF_PATH_MAX + 8]; /* "" when written in place */
} stream_out;

static wf_status stream_begin(const char *path, stream_out *so)
{
    memset(so, 0, sizeof *so);
    so->path = path;
    if (!strcmp(path, "-")) {
        so->file = stdout;
        return WF_OK;
    }
    struct stat sb;
    int in_place = stat(path, &sb) == 0 && !S_ISREG(sb.st_mode);
    if (!in_place && snprintf(so->tmp, sizeof so->tmp, "%s.tmp", path) >= (int)sizeof so->tmp)
        return wf_error(WF_ERR_INPUT, "%.80s...: stream file name too long", path);
    so->file = fopen(in_place ? path : so->tmp, "wb");
    if (!so->file)
        return wf_error(WF_ERR_IO, "%s: cannot create stream file: %s", in_place ? path : so->tmp, strerror(errno));
    return WF_OK;
}

/* Flushes and closes; renames the temporary file over path when st and every write were
 * good, else removes it. Returns the first failure. */
static wf_status stream_end(stream_out *so, wf_status st)
{
    char why[1024];
    snprintf(why, sizeof why, "%s", st ? wf_error_message() : "");
    if (fflush(so->file) != 0 && !st) st = wf_error(WF_ERR_IO, "%s: write failed: %s", so->path, strerror(errno));
    if (so->file != stdout && fclose(so->file) != 0 && !st)
        st = wf_error(WF_ERR_IO, "%s: close failed: %s", so->path, strerror(errno));
    if (so->tmp[0]) {
        if (!st) st = wf_file_rename(so->tmp, so->path);
        if (st) remove(so->tmp);
    }
    if (st && why[0]) wf_error(st, "%s", why); /* the first failure's message, not a later one's */
    return st;
}

/* The catalogs and the job's supernovae, read on a helper thread while the scene's optics are
 * built (wf_scene_prepare): with more than one thread the catalog (~15 ms for GalSim's
 * scene) is then off the set-up's serial path. */
typedef struct loader_job {
    const wf_pipeline_job *pj;
    wf_scene_inputs *in;
    wf_scene_sn *sne;
    size_t nsne;
    wf_status st;
    char message[1024]; /* the error message is per thread: carried back */
} loader_job;

static void *load_inputs(void *arg)
{
    loader_job *j = arg;
    j->st = wf_pipeline_load_catalogs(j->pj->cfg, j->in);
    if (!j->st) j->st = gather_sne(j->pj, j->in, &j->sne, &j->nsne);
    if (j->st) snprintf(j->message, sizeof j->message, "%s", wf_error_message());
    return NULL;
}

double wf_pipeline_exptime(const wf_config *cfg, const wf_clock *clock)
{
    return cfg->ro.mode == WF_MODE_SINGLE ? cfg->ro.exptime : wf_clock_exposure_time(clock);
}

void wf_pipeline_scene_setup(const wf_config *cfg, const wf_clock *clock, int threads, wf_scene_setup *ss)
{
    wf_scene_setup_default(ss);
    ss->ra = cfg->ra;
    ss->dec = cfg->dec;
    ss->pa = cfg->pa;
    ss->sca = (int)cfg->ro.sca;
    snprintf(ss->filter, sizeof ss->filter, "%s", cfg->filter);
    ss->mjd = cfg->mjd;
    snprintf(ss->data_dir, sizeof ss->data_dir, "%s", cfg->data_dir);
    ss->ncols = cfg->ro.ncols;
    ss->nrows = cfg->ro.nrows;
    ss->pupil_bin = 1 << cfg->pupil_bin;
    ss->psf_oversample = cfg->psf_oversample;
    ss->psf_nlambda = cfg->psf_nlambda;
    ss->jitter = cfg->psf_jitter;
    ss->diffusion = cfg->psf_diffusion;
    ss->bright_mag = cfg->psf_bright_mag;
    ss->flux_fraction = cfg->flux_fraction;
    ss->core_radius = cfg->psf_core_radius;
    ss->core_levels = cfg->psf_core_levels;
    ss->noise_tolerance = cfg->noise_tolerance;
    ss->exptime = wf_pipeline_exptime(cfg, clock);
    ss->sky_on = cfg->sky_on;
    ss->stray_light = cfg->stray_light;
    ss->pool_bytes = (size_t)(cfg->stamp_pool_mib * 1048576.0);
    ss->threads = threads;
}

wf_status wf_pipeline_plane_key(const wf_pipeline_job *pj, int layer, char key[65])
{
    wf_config *kc = malloc(sizeof *kc);
    if (!kc) return wf_error(WF_ERR_NOMEM, "out of memory");
    *kc = *pj->cfg;
    kc->mjd = 0.0;
    kc->ro.exposure = 0;
    /* the caller's header lines (a survey's plan row) carry the date: left out */
    wf_digest_inputs din = {kc, pj->clock, NULL, pj->replay, pj->injector, NULL, 0, pj->version};
    wf_digest d;
    wf_status st = wf_digest_product(pj->digests, &din, &d);
    free(kc);
    if (st) return st;
    wf_sha256 h;
    wf_sha256_init(&h);
    char text[1024];
    /* and the build: the source digest is in the version, but a compiler, libm or FFTW of
     * another version may round differently (ranks on nodes that share a folder) */
    const uint32_t one = 1;
    int n = snprintf(text, sizeof text, "wfisim static plane 1\n%s\nlayer %d\ncc %s\nfftw %s\nlibc %s\n%s-endian\n",
                     d.whole, layer != 0, __VERSION__, fftw_version, gnu_get_libc_version(),
                     *(const unsigned char *)&one ? "little" : "big");
    if (n < 0 || (size_t)n >= sizeof text) return wf_error(WF_ERR_INTERNAL, "plane key: text too long");
    wf_sha256_update(&h, text, (size_t)n);
    wf_sha256_hex(&h, key);
    return WF_OK;
}

wf_status wf_pipeline_expose(wf_pipeline_job *pj)
{
    const wf_config *cfg = pj->cfg;
    pj->image_path[0] = pj->truth_path[0] = '\0';
    pj->nsne_drawn = 0;
    pj->plane_found = pj->plane_not_kept = 0;
    wf_plane_cache_stats before;
    if (pj->planes) wf_plane_cache_get_stats(pj->planes, &before);
    int T = cfg->threads < 1 ? 1 : cfg->threads;
    wf_scene_source *scenes = calloc((size_t)T, sizeof *scenes);
    wf_scene_replay *replays = calloc((size_t)T, sizeof *replays);
    wf_scene_grid grid;
    wf_status st = WF_OK;
    int opened = 0;
    wf_scene_inputs inputs;
    memset(&inputs, 0, sizeof inputs);
    wf_scene *objscene = NULL;
    wf_scene_sn *sne = NULL;
    size_t nsne = 0;
    char *extra = NULL;
    const size_t extra_cap = WF_READOUT_META_MAX / 2; /* the readout's own lines take the rest */
    char made_dir[WF_PATH_MAX] = "";
    if (!scenes || !replays || !(extra = malloc(extra_cap))) { st = wf_error(WF_ERR_NOMEM, "out of memory"); goto done; }
    wf_pipeline_grid(cfg, &grid);
    int objects = !pj->replay && cfg->scene_kind != 2;
    if (objects) {
        wf_scene_setup ss;
        wf_pipeline_scene_setup(cfg, pj->clock, T, &ss);
        ss.psf_cache = pj->psfs;
        /* one thread: the catalogs first, so that a bad one fails before any PSF work; either
         * way a catalog's failure is the one reported. Both sides may read FITS files (a FITS
         * catalog, the pupil), so only with a cfitsio built reentrant (Debian's is). */
        loader_job lj = {pj, &inputs, NULL, 0, WF_OK, ""};
        pthread_t lt;
        int overlap = T > 1 && fits_is_reentrant() && pthread_create(&lt, NULL, load_inputs, &lj) == 0;
        if (!overlap) load_inputs(&lj);
        wf_status pst = overlap || !lj.st ? wf_scene_prepare(&ss, &objscene) : WF_OK;
        char prepare_msg[1024];
        snprintf(prepare_msg, sizeof prepare_msg, "%s", pst ? wf_error_message() : "");
        if (overlap) pthread_join(lt, NULL);
        sne = lj.sne;
        nsne = lj.nsne;
        if (lj.st) { st = wf_error(lj.st, "%s", lj.message); goto done; }
        if (pst) { st = wf_error(pst, "%s", prepare_msg); goto done; }
        if (pj->layer) { /* the bright objects' layer, for later exposures' persistence */
            wf_scene_stats pre;
            wf_scene_get_stats(objscene, &pre);
            const uint8_t *gf, *sf;
            if ((st = wf_persist_layer_flags(pj->layer, inputs.have_gal ? &inputs.gal : NULL,
                                             inputs.have_stars ? &inputs.stars : NULL, pre.psf_pixel_max, &gf, &sf)))
                goto done;
            wf_scene_set_layer(objscene, gf, sf, wf_persist_layer_row, pj->layer, wf_persist_layer_floor(pj->layer));
        }
        if (pj->planes) { /* the static plane: from the scene's earlier exposures, or for its later */
            char key[65];
            int found;
            wf_plane_entry *pe;
            if ((st = wf_pipeline_plane_key(pj, pj->layer != NULL, key))) goto done;
            if ((st = wf_plane_entry_open(pj->planes, key, cfg->ro.ncols, cfg->ro.nrows, pj->layer != NULL, &pe,
                                          &found)))
                goto done;
            wf_scene_set_plane(objscene, pe, found);
            pj->plane_found = found;
        }
        if ((st = wf_scene_populate(objscene, inputs.have_gal ? &inputs.gal : NULL,
                                    inputs.have_stars ? &inputs.stars : NULL, sne, nsne)))
            goto done;
        wf_scene_stats sst;
        wf_scene_get_stats(objscene, &sst);
        pj->nsne_drawn = (size_t)sst.sne;
        if (!cfg->quiet)
            fprintf(stderr, "wfisim: scene of %ld galaxies and %ld stars on SCA %u in %s, sky %.4f-%.4f "
                    "e-/pixel/s, PSF at %.1f nm, built in %.2f s\n", sst.galaxies, sst.stars, cfg->ro.sca,
                    cfg->filter, sst.sky_min, sst.sky_max, sst.psf_lambda_nm, sst.build_seconds);
    }
    for (int i = 0; i < T; i++) {
        if (objects) {
            if ((st = wf_scene_source_for(objscene, i, &scenes[i]))) goto done;
        } else if (pj->replay) {
            if ((st = wf_scene_replay_open(&replays[i], pj->replay, &scenes[i]))) goto done;
            opened = i + 1;
            if (replays[i].ncols != cfg->ro.ncols || replays[i].nrows != cfg->ro.nrows) {
                st = wf_error(WF_ERR_INPUT, "%s: recording is %d x %d, the SCA is %d x %d", pj->replay,
                              replays[i].ncols, replays[i].nrows, cfg->ro.ncols, cfg->ro.nrows);
                goto done;
            }
        } else if ((st = wf_scene_grid_source(&grid, &scenes[i]))) goto done;
    }
    static const char *const kinds[] = {"synthetic", "catalog", "grid", "galsim"};
    int len = snprintf(extra, extra_cap,
                       "hdr.FILTER = %s / optical element\n"
                       "hdr.SCENE = %s / scene source\n"
                       "hdr.ORIGIN = wfisim %s / software\n",
                       cfg->filter, pj->replay ? "replay" : inputs.galsim_scene ? "galsim" : kinds[cfg->scene_kind],
                       pj->version ? pj->version : "?");
    if (objects) {
        len += snprintf(extra + len, extra_cap - (size_t)len,
                        "hdr.RA_PNT = %.10f / [deg] boresight right ascension\n"
                        "hdr.DEC_PNT = %.10f / [deg] boresight declination\n"
                        "hdr.PA_PNT = %.10f / [deg] observatory position angle (GalSim getWCS PA)\n"
                        "hdr.MJD-OBS = %.8f / [d] exposure mid-time\n",
                        cfg->ra, cfg->dec, cfg->pa, cfg->mjd);
        if ((st = wf_scene_wcs_meta(objscene, extra + len, extra_cap - (size_t)len))) goto done;
    } else {
        snprintf(extra + len, extra_cap - (size_t)len,
                 "hdr.SKYRATE = %.9g / sky rate of the grid scene, e-/pixel/s\n", cfg->sky_rate);
    }
    if (pj->meta_extra) {
        size_t used = strlen(extra);
        if (used + strlen(pj->meta_extra) + 1 > extra_cap) { st = wf_error(WF_ERR_INPUT, "extra header lines too long"); goto done; }
        memcpy(extra + used, pj->meta_extra, strlen(pj->meta_extra) + 1);
    }
    /* what shapes the product, in its primary header: a resumed survey run compares it
     * (tools/digest.h) */
    const wf_config *dcfg = cfg;
    wf_config canon;
    if (inputs.galsim_scene && cfg->scene_kind != 3) {
        /* a GalSim scene given as scene.kind catalog (recognised by its columns) is the same
         * input as scene.kind galsim: the same digest, so the same product bytes */
        canon = *cfg;
        canon.scene_kind = 3;
        dcfg = &canon;
    }
    wf_digest_inputs din = {dcfg, pj->clock, pj->meta_extra, pj->replay, pj->injector, pj->sne, pj->nsne, pj->version};
    if ((st = wf_digest_product(pj->digests, &din, &pj->digest))) goto done;
    if ((st = wf_digest_meta(&pj->digest, dcfg, extra, extra_cap))) goto done;

    wf_expose_job job = {0};
    job.ro = cfg->ro;
    job.ro.time_variable = objscene && wf_scene_time_variable(objscene);
    if (pj->persist) job.ro.persist.source = *pj->persist; /* survey run's history (tools/persist.h) */
    job.clock = *pj->clock;
    job.noise = (wf_noise){WF_NOISE_PHILOX, cfg->seed, cfg->ro.exposure, cfg->ro.sca};
    job.scenes = scenes;
    job.threads = T;
    job.progress = !cfg->quiet && isatty(STDERR_FILENO);
    job.meta_extra = extra;

    wf_link link;
    wf_link_stream ls;
    if (pj->stream) {
        stream_out so;
        if ((st = stream_begin(pj->stream, &so))) goto done;
        wf_link_stream_open(&ls, so.file, pj->stream, &link);
        job.link = &link;
        st = stream_end(&so, wf_expose_run(&job));
        wf_link_stream_close(&ls);
        goto done;
    }
    /* In-process: the same packets go through a pipe to an assembler thread, so the FITS is
     * identical to `wfisim expose --stream - | wfisim assemble -`. Their payloads are not
     * deflated: the link never leaves the process, and compression changes only the wire
     * bytes, not what is assembled (0.7 CPU-s of deflate and inflate per SCA saved). The
     * pipe is wfisim's own (hal/link.h): an OS pipe cost ~5% of a GalSim-scene run in system
     * calls, kernel copies and wake-ups. Its 4 MiB ring holds a few tiles' packets. */
    job.ro.compress = 0;
    if ((st = wf_file_make_dir_noting(cfg->out_dir, made_dir))) goto done;
    wf_link_pipe lp;
    if ((st = wf_link_pipe_open(&lp, (size_t)4 << 20, "in-process stream", &link))) goto done;
    assembler_thread at = {0};
    at.in = &lp;
    wf_pipeline_assemble_options(cfg, &at.opt);
    pthread_t th;
    if (pthread_create(&th, NULL, assemble_main, &at) != 0) {
        wf_link_pipe_free(&lp);
        st = wf_error(WF_ERR_IO, "cannot start the assembler thread");
        goto done;
    }
    job.link = &link;
    st = wf_expose_run(&job);
    char expose_msg[1024];
    snprintf(expose_msg, sizeof expose_msg, "%s", wf_error_message());
    wf_link_pipe_close_write(&lp);
    pthread_join(th, NULL);
    /* the first failure is the one to report: the readout's (the first in time, among its
     * threads), unless that was a send refused because the assembler had stopped: then the
     * assembler's says why */
    int refused = st && lp.refused && strstr(expose_msg, WF_LINK_PIPE_REFUSED);
    wf_link_pipe_free(&lp);
    if (st && !refused) { wf_error(st, "%s", expose_msg); goto done; }
    if (at.status) { st = wf_error(at.status, "%s", at.message); goto done; }
    if (st) { wf_error(st, "%s", expose_msg); goto done; }
    snprintf(pj->image_path, sizeof pj->image_path, "%s", at.path);
    if (!cfg->quiet)
        fprintf(stderr, "wfisim: wrote %s (arena %.1f MiB per readout instance, %.1f MiB used)\n",
                at.path, job.arena_bytes / 1048576.0, job.arena_high_water / 1048576.0);
done:
    if (!st && objscene && !cfg->quiet) {
        long stamps, pieces;
        size_t pool;
        wf_scene_render_stats(objscene, &stamps, &pieces, &pool);
        fprintf(stderr, "wfisim: %ld stamps drawn whole, %ld in pieces, stamp pool high water %.1f MiB\n",
                stamps, pieces, pool / 1048576.0);
    }
    if (!st && objscene) { /* truth of what was drawn, beside the image */
        char tpath[WF_PATH_MAX + 64];
        wf_pipeline_paths(cfg->out_dir, cfg->ro.exposure, cfg->ro.sca, pj->image_path, pj->truth_path,
                          sizeof pj->image_path);
        snprintf(tpath, sizeof tpath, "%s", pj->truth_path);
        if (!(pj->stream && (st = wf_file_make_dir(cfg->out_dir)))) st = wf_scene_write_truth(objscene, tpath, pj->digest.whole);
        if (!st && !cfg->quiet) fprintf(stderr, "wfisim: wrote %s\n", tpath);
    }
    if (st) wf_file_unmake_dir(cfg->out_dir, made_dir);
    wf_scene_destroy(objscene); /* which closes its plane's entry: kept now, or not */
    if (pj->planes) {
        wf_plane_cache_stats after;
        wf_plane_cache_get_stats(pj->planes, &after);
        pj->plane_not_kept = after.not_kept > before.not_kept;
    }
    wf_pipeline_inputs_free(&inputs);
    free(sne);
    free(extra);
    for (int i = 0; i < opened; i++) wf_scene_replay_close(&replays[i]);
    free(scenes);
    free(replays);
    return st;
}

