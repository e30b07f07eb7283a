/* wfisim: one program, subcommands. The host side: parses options and configs, wires the
 * HAL implementations to the firmware and the assembler, and reports errors. */
#include <errno.h>
#include <fitsio.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "hal/link.h"
#include "hal/scene.h"
#include "sim/catalog.h"
#include "sim/scene.h"
#include "sim/skyindex.h"
#include "sim/synth.h"
#include "sim/wcs.h"
#include "tools/assemble.h"
#include "tools/config.h"
#include "tools/expose.h"
#include "tools/psfcmd.h"
#include "tools/surveycmd.h"

#define WFISIM_VERSION "0.1.0"

static const char *usage_text =
    "usage: wfisim <command> [options]\n"
    "\n"
    "commands:\n"
    "  demo                 one full SCA exposure of the built-in scene, up the ramp, to FITS\n"
    "  expose               one exposure of the configured scene (--stream FILE|- for packets)\n"
    "  assemble FILE|-      packet stream -> FITS (SCI, ERR, DQ, RESULTANTS)\n"
    "  record --rates FILE  write the scene's rate rows to a replay file\n"
    "  stamp --id ID        one catalog object's stamp (PSF, pixel, e-/s) -> DIR/stamp_ID.fits\n"
    "  psf --filter F --sca N --out F   a Roman PSF image (see wfisim psf --help)\n"
    "  survey plan --out F  the deep-tier observation plan and its coverage map (docs/SURVEY.md)\n"
    "  config doc           print the reference of every configuration key (docs/CONFIG.md)\n"
    "  config check FILE    load a configuration file and report the first problem\n"
    "\n"
    "options of the rendering commands:\n"
    "  --out DIR            output directory [out]           --seed N     noise seed [1]\n"
    "  --tile-rows N        rows per tile [64]               --threads N  readout threads [1]\n"
    "  --mode ramp|single   up the ramp or GalSim single frame [ramp]\n"
    "  --sampling per-read|direct   how resultants are drawn [per-read]\n"
    "  --config FILE        YAML configuration (see docs/CONFIG.md)\n"
    "  --set KEY=VALUE      override one configuration key (repeatable)\n"
    "  --stream FILE|-      write the packet stream instead of FITS\n"
    "  --replay FILE        take the scene from a rate recording\n"
    "  --ra D --dec D --pa D --sca N --filter F --mjd M --exptime S\n"
    "                       pointing (PA as galsim.roman.getWCS), SCA, filter, mid-time, and\n"
    "                       the single-frame exposure time (ramp mode: the MA table's)\n"
    "  --catalog FILE [--stars FILE]   draw these catalogs (FITS or CSV, docs/CATALOGS.md)\n"
    "  --data DIR           Roman data directory (default $WFISIM_DATA; none: built-ins)\n"
    "  --quiet              no progress output\n";

static int fail(const char *what, wf_status st)
{
    fprintf(stderr, "wfisim: %s: %s\n", what, wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

typedef struct cli {
    wf_config cfg;
    wf_clock clock;
    const char *stream;
    const char *replay;
    const char *rates;
    const char *positional;
    const char *id;
} cli;

/* Options that are shorthands for configuration keys. */
static const struct { const char *flag, *key; } shorthands[] = {
    {"--out", "run.out"},           {"--seed", "seed"},         {"--tile-rows", "readout.tile_rows"},
    {"--threads", "run.threads"},   {"--mode", "exposure.mode"}, {"--sampling", "exposure.sampling"},
    {"--exposure", "exposure.id"},  {"--sca", "exposure.sca"},  {"--ma-table", "readout.ma_table"},
    {"--filter", "exposure.filter"},
    {"--ra", "pointing.ra"},        {"--dec", "pointing.dec"},  {"--pa", "pointing.pa"},
    {"--mjd", "exposure.mjd"},      {"--exptime", "exposure.exptime"},
    {"--data", "paths.data"},       {"--stars", "scene.stars"},
};

static int parse(int argc, char **argv, cli *c)
{
    memset(c, 0, sizeof *c);
    wf_config_defaults(&c->cfg);
    wf_status st;
    /* the config file first, wherever it stands, so that flags override it */
    for (int i = 0; i < argc; i++)
        if (!strcmp(argv[i], "--config")) {
            if (i + 1 >= argc) { fprintf(stderr, "wfisim: --config needs a file\n"); return 2; }
            if ((st = wf_config_load(&c->cfg, argv[i + 1]))) return fail("config", st);
        }
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const char *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--config")) { i++; continue; }
        if (!strcmp(a, "--quiet")) { c->cfg.quiet = 1; continue; }
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { fputs(usage_text, stdout); exit(0); }
        int done = 0;
        for (size_t k = 0; k < sizeof shorthands / sizeof *shorthands; k++)
            if (!strcmp(a, shorthands[k].flag)) {
                if (!val) { fprintf(stderr, "wfisim: %s needs a value\n", a); return 2; }
                char buf[2 * WF_PATH_MAX];
                snprintf(buf, sizeof buf, "%s=%s", shorthands[k].key, val);
                if ((st = wf_config_set(&c->cfg, buf, a))) return fail("option", st);
                i++;
                done = 1;
                break;
            }
        if (done) continue;
        if (!strcmp(a, "--set")) {
            if (!val) { fprintf(stderr, "wfisim: --set needs KEY=VALUE\n"); return 2; }
            if ((st = wf_config_set(&c->cfg, val, "--set"))) return fail("option", st);
            i++;
        } else if (!strcmp(a, "--catalog") && val) { /* a catalog file implies a catalog scene */
            char buf[2 * WF_PATH_MAX];
            snprintf(buf, sizeof buf, "scene.catalog=%s", val);
            if ((st = wf_config_set(&c->cfg, buf, a)) || (st = wf_config_set(&c->cfg, "scene.kind=catalog", a)))
                return fail("option", st);
            i++;
        } else if (!strcmp(a, "--stream") && val) { c->stream = val; i++; }
        else if (!strcmp(a, "--replay") && val) { c->replay = val; i++; }
        else if (!strcmp(a, "--rates") && val) { c->rates = val; i++; }
        else if (!strcmp(a, "--id") && val) { c->id = val; i++; }
        else if (a[0] == '-' && a[1] == '-') {
            fprintf(stderr, "wfisim: unknown option '%s' (see wfisim --help)\n", a);
            return 2;
        } else if (!c->positional) c->positional = a;
        else { fprintf(stderr, "wfisim: unexpected argument '%s'\n", a); return 2; }
    }
    if ((st = wf_config_finish(&c->cfg, &c->clock))) return fail("config", st);
    return 0;
}

static wf_status make_dir(const char *dir)
{
    char buf[WF_PATH_MAX];
    snprintf(buf, sizeof buf, "%s", dir);
    for (char *p = buf + 1; *p; p++)
        if (*p == '/') {
            *p = '\0';
            if (mkdir(buf, 0777) != 0 && errno != EEXIST) return wf_error(WF_ERR_IO, "%s: cannot create directory", buf);
            *p = '/';
        }
    if (mkdir(buf, 0777) != 0 && errno != EEXIST) return wf_error(WF_ERR_IO, "%s: cannot create directory", buf);
    return WF_OK;
}

static void grid_from_config(const wf_config *cfg, wf_scene_grid *g)
{
    g->ncols = cfg->ro.ncols;
    g->nrows = cfg->ro.nrows;
    g->sky = cfg->sky_rate;
    g->flux = cfg->grid_flux;
    g->sigma = cfg->grid_sigma;
    g->spacing = cfg->grid_spacing;
}

/* Catalogs of the scene: a synthetic field around the SCA, files, or a GalSim scene. */
typedef struct scene_inputs {
    wf_catalog gal, stars, sne;
    int have_gal, have_stars, have_sne;
} scene_inputs;

static void scene_inputs_free(scene_inputs *in)
{
    if (in->have_gal) wf_catalog_free(&in->gal);
    if (in->have_stars) wf_catalog_free(&in->stars);
    if (in->have_sne) wf_catalog_free(&in->sne);
}

/* The SCA's footprint on the sky, widened by the largest stamp reach (70"), so that objects
 * just off the SCA whose light reaches onto it are kept. */
static wf_status sca_region(const wf_config *cfg, wf_skyregion *reg)
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
    return wf_skyindex_polygon(ra, dec, 4, 70.0, reg);
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

static wf_status load_catalogs(const wf_config *cfg, scene_inputs *in)
{
    memset(in, 0, sizeof *in);
    wf_skyregion reg;
    wf_status st = sca_region(cfg, &reg);
    if (st) return st;
    if (cfg->scene_kind == 0) { /* synthetic: only the cells the SCA (and stamps reaching it) see */
        wf_synth_config sc;
        wf_synth *syn;
        wf_synth_defaults(&sc);
        sc.seed = cfg->seed;
        if ((st = wf_synth_create(&sc, &syn))) return st;
        st = wf_synth_select(syn, &reg, &in->gal, &in->stars);
        wf_synth_free(syn);
        if (!st) in->have_gal = in->have_stars = 1;
        return st;
    }
    if (cfg->scene_kind == 3) {
        if (!cfg->catalog[0]) return wf_error(WF_ERR_INPUT, "scene.kind galsim needs scene.catalog");
        st = wf_catalog_read_galsim_scene(cfg->catalog, &in->gal, &in->stars, &in->sne);
        if (!st) in->have_gal = in->have_stars = in->have_sne = 1;
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
    FILE *in;
    wf_assemble_options opt;
    wf_status status;
    char message[1024];
    char path[WF_PATH_MAX];
} assembler_thread;

static void *assemble_main(void *arg)
{
    assembler_thread *a = arg;
    a->status = wf_assemble_stream(a->in, "in-process stream", &a->opt, a->path, sizeof a->path);
    if (a->status) snprintf(a->message, sizeof a->message, "%s", wf_error_message());
    /* drain so that a writer blocked on a full pipe sees EOF handling, not a hang */
    char sink[65536];
    while (fread(sink, 1, sizeof sink, a->in) > 0) {}
    return NULL;
}

static int run_exposure(cli *c, int demo)
{
    wf_config *cfg = &c->cfg;
    int T = cfg->threads < 1 ? 1 : cfg->threads;
    wf_scene_source *scenes = calloc((size_t)T, sizeof *scenes);
    wf_scene_replay *replays = calloc((size_t)T, sizeof *replays);
    wf_scene_grid grid;
    wf_status st = WF_OK;
    int rc = 0, opened = 0;
    scene_inputs inputs;
    memset(&inputs, 0, sizeof inputs);
    wf_scene *objscene = NULL;
    char *extra = NULL;
    const size_t extra_cap = 64 * 1024;
    if (!scenes || !replays || !(extra = malloc(extra_cap))) { st = wf_error(WF_ERR_NOMEM, "out of memory"); goto done; }
    grid_from_config(cfg, &grid);
    int objects = !c->replay && cfg->scene_kind != 2;
    if (objects) {
        if ((st = load_catalogs(cfg, &inputs))) goto done;
        wf_scene_setup ss;
        wf_scene_setup_default(&ss);
        ss.ra = cfg->ra;
        ss.dec = cfg->dec;
        ss.pa = cfg->pa;
        ss.sca = (int)cfg->ro.sca;
        snprintf(ss.filter, sizeof ss.filter, "%s", cfg->filter);
        ss.mjd = cfg->mjd;
        snprintf(ss.data_dir, sizeof ss.data_dir, "%s", cfg->data_dir);
        ss.ncols = cfg->ro.ncols;
        ss.nrows = cfg->ro.nrows;
        ss.pupil_bin = 1 << cfg->pupil_bin;
        ss.psf_oversample = cfg->psf_oversample;
        ss.flux_fraction = cfg->flux_fraction;
        ss.threads = T;
        if ((st = wf_scene_create(&ss, inputs.have_gal ? &inputs.gal : NULL,
                                  inputs.have_stars ? &inputs.stars : NULL, &objscene)))
            goto done;
        wf_scene_stats sst;
        wf_scene_get_stats(objscene, &sst);
        if (!cfg->quiet)
            fprintf(stderr, "wfisim: scene of %ld galaxies and %ld stars on SCA %u in %s, sky %.4f-%.4f "
                    "e-/pixel/s, PSF at %.1f nm, built in %.2f s\n", sst.galaxies, sst.stars, cfg->ro.sca,
                    cfg->filter, sst.sky_min, sst.sky_max, sst.psf_lambda_nm, sst.build_seconds);
    }
    for (int i = 0; i < T; i++) {
        if (objects) {
            if ((st = wf_scene_source_for(objscene, i, &scenes[i]))) goto done;
        } else if (c->replay) {
            if ((st = wf_scene_replay_open(&replays[i], c->replay, &scenes[i]))) goto done;
            opened = i + 1;
            if (replays[i].ncols != cfg->ro.ncols || replays[i].nrows != cfg->ro.nrows) {
                st = wf_error(WF_ERR_INPUT, "%s: recording is %d x %d, the SCA is %d x %d", c->replay,
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
                       cfg->filter, c->replay ? "replay" : kinds[cfg->scene_kind], WFISIM_VERSION);
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
    (void)demo;

    wf_expose_job job = {0};
    job.ro = cfg->ro;
    job.clock = c->clock;
    job.noise = (wf_noise){WF_NOISE_PHILOX, cfg->seed, cfg->ro.exposure, cfg->ro.sca};
    job.scenes = scenes;
    job.threads = T;
    job.progress = !cfg->quiet && isatty(STDERR_FILENO);
    job.meta_extra = extra;

    wf_link link;
    wf_link_stream ls;
    if (c->stream) {
        FILE *f = strcmp(c->stream, "-") ? fopen(c->stream, "wb") : stdout;
        if (!f) { st = wf_error(WF_ERR_IO, "%s: cannot create stream file", c->stream); goto done; }
        wf_link_stream_open(&ls, f, c->stream, &link);
        job.link = &link;
        st = wf_expose_run(&job);
        if (fflush(f) != 0 && !st) st = wf_error(WF_ERR_IO, "%s: write failed", c->stream);
        if (f != stdout && fclose(f) != 0 && !st) st = wf_error(WF_ERR_IO, "%s: close failed", c->stream);
        wf_link_stream_close(&ls);
        goto done;
    }
    /* In-process: the same bytes go through a pipe to an assembler thread, so the FITS is
     * identical to `wfisim expose --stream - | wfisim assemble -`. */
    if ((st = make_dir(cfg->out_dir))) goto done;
    int fds[2];
    if (pipe(fds) != 0) { st = wf_error(WF_ERR_IO, "cannot create a pipe"); goto done; }
    FILE *w = fdopen(fds[1], "wb"), *r = fdopen(fds[0], "rb");
    assembler_thread at = {0};
    at.in = r;
    at.opt.out_dir = cfg->out_dir;
    at.opt.quiet = cfg->quiet;
    pthread_t th;
    pthread_create(&th, NULL, assemble_main, &at);
    wf_link_stream_open(&ls, w, "in-process stream", &link);
    job.link = &link;
    st = wf_expose_run(&job);
    char expose_msg[1024];
    snprintf(expose_msg, sizeof expose_msg, "%s", wf_error_message());
    fclose(w);
    pthread_join(th, NULL);
    fclose(r);
    wf_link_stream_close(&ls);
    if (st) { wf_error(st, "%s", expose_msg); goto done; }
    if (at.status) { st = wf_error(at.status, "%s", at.message); goto done; }
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
        snprintf(tpath, sizeof tpath, "%s/wfisim_e%06u_sca%02u_truth.fits", cfg->out_dir, cfg->ro.exposure,
                 cfg->ro.sca);
        if (!(c->stream && (st = make_dir(cfg->out_dir)))) st = wf_scene_write_truth(objscene, tpath);
        if (!st && !cfg->quiet) fprintf(stderr, "wfisim: wrote %s\n", tpath);
    }
    wf_scene_destroy(objscene);
    scene_inputs_free(&inputs);
    free(extra);
    for (int i = 0; i < opened; i++) wf_scene_replay_close(&replays[i]);
    free(scenes);
    free(replays);
    if (st) rc = fail(demo ? "demo" : "expose", st);
    return rc;
}

static int cmd_assemble(cli *c)
{
    if (!c->positional) { fprintf(stderr, "wfisim assemble: give a stream file or '-'\n"); return 2; }
    wf_status st = make_dir(c->cfg.out_dir);
    if (st) return fail("assemble", st);
    FILE *in = strcmp(c->positional, "-") ? fopen(c->positional, "rb") : stdin;
    if (!in) { wf_error(WF_ERR_IO, "%s: cannot open", c->positional); return fail("assemble", WF_ERR_IO); }
    wf_assemble_options opt = {c->cfg.out_dir, c->cfg.quiet};
    char path[WF_PATH_MAX] = "";
    st = wf_assemble_stream(in, c->positional, &opt, path, sizeof path);
    if (in != stdin) fclose(in);
    return st ? fail("assemble", st) : 0;
}

/* Keeps only the row with this id (no copy when absent: *found = 0). */
static wf_status keep_id(wf_catalog *cat, long long id, int *found)
{
    for (size_t i = 0; i < cat->n; i++)
        if (cat->id[i] == id) {
            uint32_t row = (uint32_t)i;
            wf_catalog sub;
            wf_status st = wf_catalog_subset(cat, &row, 1, &sub);
            if (st) return st;
            wf_catalog_free(cat);
            *cat = sub;
            *found = 1;
            return WF_OK;
        }
    cat->n = 0;
    return WF_OK;
}

/* One object's stamp as the scene draws it (PSF of the SCA and filter, pixel response,
 * e-/s), for users and checks: the counterpart of GalSim's obj.drawImage. */
static int cmd_stamp(cli *c)
{
    wf_config *cfg = &c->cfg;
    if (!c->id) { fprintf(stderr, "wfisim stamp: give --id ID (and --catalog FILE or a scene)\n"); return 2; }
    char *end;
    long long id = strtoll(c->id, &end, 10);
    if (end == c->id || *end) { fprintf(stderr, "wfisim stamp: --id '%s' is not an integer\n", c->id); return 2; }
    if (cfg->scene_kind == 2) { fprintf(stderr, "wfisim stamp: the grid scene has no catalog ids\n"); return 2; }
    scene_inputs in;
    wf_scene *scene = NULL;
    double *pix = NULL;
    wf_status st = load_catalogs(cfg, &in);
    int found = 0;
    if (!st && in.have_gal) st = keep_id(&in.gal, id, &found);
    if (!st && in.have_stars) st = keep_id(&in.stars, id, &found);
    if (!st && !found) st = wf_error(WF_ERR_INPUT, "object %lld is not in the catalog near SCA %u of this pointing", id, cfg->ro.sca);
    wf_scene_setup ss;
    wf_scene_setup_default(&ss);
    ss.ra = cfg->ra, ss.dec = cfg->dec, ss.pa = cfg->pa, ss.sca = (int)cfg->ro.sca, ss.mjd = cfg->mjd;
    snprintf(ss.filter, sizeof ss.filter, "%s", cfg->filter);
    snprintf(ss.data_dir, sizeof ss.data_dir, "%s", cfg->data_dir);
    ss.pupil_bin = 1 << cfg->pupil_bin;
    ss.psf_oversample = cfg->psf_oversample;
    ss.flux_fraction = cfg->flux_fraction;
    ss.sky_on = 0;
    if (!st) st = wf_scene_create(&ss, in.have_gal && in.gal.n ? &in.gal : NULL, in.have_stars && in.stars.n ? &in.stars : NULL, &scene);
    if (!st && wf_scene_object_count(scene) == 0)
        st = wf_error(WF_ERR_INPUT, "object %lld does not reach SCA %u of this pointing", id, cfg->ro.sca);
    wf_scene_object info;
    int x0 = 0, y0 = 0, nx = 0, ny = 0;
    if (!st) st = wf_scene_draw_object(scene, 0, &info, &x0, &y0, &nx, &ny, &pix);
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/stamp_%lld.fits", cfg->out_dir, id);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    if (!st) st = make_dir(cfg->out_dir);
    if (!st) {
        fitsfile *f;
        int status = 0;
        long naxes[2] = {nx, ny};
        remove(tmp);
        fits_create_diskfile(&f, tmp, &status);
        fits_create_img(f, DOUBLE_IMG, 2, naxes, &status);
        fits_write_key_lng(f, "OBJID", info.id, "catalog id", &status);
        fits_write_key_str(f, "OBJTYPE", info.kind ? "star" : "galaxy", "", &status);
        fits_write_key_str(f, "FILTER", cfg->filter, "", &status);
        fits_write_key_lng(f, "SCA", cfg->ro.sca, "", &status);
        fits_write_key_dbl(f, "RA_OBJ", info.ra, 12, "[deg]", &status);
        fits_write_key_dbl(f, "DEC_OBJ", info.dec, 12, "[deg]", &status);
        fits_write_key_dbl(f, "X_OBJ", info.x + 1, 10, "object centre, FITS pixel on the SCA", &status);
        fits_write_key_dbl(f, "Y_OBJ", info.y + 1, 10, "object centre, FITS pixel on the SCA", &status);
        fits_write_key_lng(f, "X0_SCA", x0 + 1, "SCA FITS column of stamp pixel 1", &status);
        fits_write_key_lng(f, "Y0_SCA", y0 + 1, "SCA FITS row of stamp pixel 1", &status);
        fits_write_key_dbl(f, "MAG", info.mag, 6, "AB magnitude in FILTER", &status);
        fits_write_key_dbl(f, "FLUX", info.flux, 10, "[electron/s] total flux", &status);
        fits_write_key_lng(f, "PUPILBIN", 1 << cfg->pupil_bin, "", &status);
        fits_write_key_lng(f, "PSFOVER", cfg->psf_oversample, "PSF image oversampling", &status);
        fits_write_key_dbl(f, "FLUXFRAC", cfg->flux_fraction, 6, "stamp holds at least this", &status);
        fits_write_key_str(f, "BUNIT", "electron/s", "", &status);
        long first[2] = {1, 1};
        fits_write_pix(f, TDOUBLE, first, (long long)nx * ny, pix, &status);
        int cs = 0;
        fits_close_file(f, &cs);
        if (status || cs) {
            remove(tmp);
            st = wf_error(WF_ERR_IO, "%s: cfitsio status %d writing the stamp", path, status ? status : cs);
        } else if (rename(tmp, path) != 0) {
            remove(tmp);
            st = wf_error(WF_ERR_IO, "%s: cannot rename into place", path);
        }
    }
    if (!st && !cfg->quiet) fprintf(stderr, "wfisim: wrote %s (%d x %d, %s %lld, %.4g e-/s)\n", path, nx, ny,
                                    info.kind ? "star" : "galaxy", info.id, info.flux);
    free(pix);
    wf_scene_destroy(scene);
    scene_inputs_free(&in);
    return st ? fail("stamp", st) : 0;
}

static int cmd_record(cli *c)
{
    if (!c->rates) { fprintf(stderr, "wfisim record: give --rates FILE\n"); return 2; }
    wf_scene_grid grid;
    wf_scene_source src;
    grid_from_config(&c->cfg, &grid);
    wf_status st = wf_scene_grid_source(&grid, &src);
    float *scratch = malloc((size_t)c->cfg.ro.tile_rows * c->cfg.ro.ncols * sizeof *scratch);
    if (!scratch) return fail("record", wf_error(WF_ERR_NOMEM, "out of memory"));
    if (!st) st = wf_scene_record(&src, c->cfg.ro.ncols, c->cfg.ro.nrows, c->cfg.ro.tile_rows, scratch, c->rates);
    free(scratch);
    return st ? fail("record", st) : 0;
}

int main(int argc, char **argv)
{
    signal(SIGPIPE, SIG_IGN); /* a closed pipe is an I/O error we report, not a silent death */
    if (argc < 2) { fputs(usage_text, stderr); return 2; }
    const char *cmd = argv[1];
    if (!strcmp(cmd, "--help") || !strcmp(cmd, "-h") || !strcmp(cmd, "help")) { fputs(usage_text, stdout); return 0; }
    if (!strcmp(cmd, "--version")) { puts("wfisim " WFISIM_VERSION); return 0; }
    if (!strcmp(cmd, "survey")) return wf_cmd_survey(argc - 2, argv + 2);
    if (!strcmp(cmd, "psf")) return wf_cmd_psf(argc - 2, argv + 2);
    if (!strcmp(cmd, "config")) {
        if (argc >= 3 && !strcmp(argv[2], "doc")) { wf_config_write_doc(stdout); return 0; }
        if (argc >= 4 && !strcmp(argv[2], "check")) {
            wf_config cfg;
            wf_clock clock;
            wf_config_defaults(&cfg);
            wf_status st = wf_config_load(&cfg, argv[3]);
            if (!st) st = wf_config_finish(&cfg, &clock);
            if (st) return fail("config", st);
            printf("%s: ok\n", argv[3]);
            return 0;
        }
        fprintf(stderr, "usage: wfisim config doc | wfisim config check FILE\n");
        return 2;
    }
    cli c;
    int rc = parse(argc - 2, argv + 2, &c);
    if (rc) return rc;
    if (!strcmp(cmd, "demo")) return run_exposure(&c, 1);
    if (!strcmp(cmd, "expose")) return run_exposure(&c, 0);
    if (!strcmp(cmd, "assemble")) return cmd_assemble(&c);
    if (!strcmp(cmd, "record")) return cmd_record(&c);
    if (!strcmp(cmd, "stamp")) return cmd_stamp(&c);
    fprintf(stderr, "wfisim: unknown command '%s'\n\n%s", cmd, usage_text);
    return 2;
}
