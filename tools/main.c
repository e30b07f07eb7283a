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

#include "analysis/detect.h"
#include "analysis/efficiency.h"
#include "hal/file.h"
#include "hal/link.h"
#include "hal/scene.h"
#include "sim/survey/catalog.h"
#include "sim/fits/fitsdisk.h"
#include "sim/fits/fitsout.h"
#include "sim/draw/scene.h"
#include "sim/survey/skyindex.h"
#include "sim/survey/synth.h"
#include "sim/survey/wcs.h"
#include "sim/draw/plane_cache.h"
#include "tools/accuracy.h"
#include "tools/assemble.h"
#include "tools/config.h"
#include "tools/digest.h"
#include "tools/expose.h"
#include "tools/pipeline.h"
#include "tools/psfcmd.h"
#include "analysis/coadd.h"
#include "analysis/diff.h"
#include "analysis/hosts.h"
#include "tools/sncmd.h"
#include "tools/surveycmd.h"
#include "tools/surveyrun.h"
#ifdef WF_MPI
#include "tools/survey_mpi.h"
#endif

#define WFISIM_VERSION "0.1.0"

/* The release and the digest of the sources it was built from: what a product records as the
 * program that made it (tools/digest.h), so code that changes products changes it. */
static char version[64];

static const char *usage_text =
    "usage: wfisim <command> [options]\n"
    "\n"
    "commands:\n"
    "  demo                 one full SCA exposure of the built-in scene, up the ramp, to FITS\n"
    "  expose               one exposure of the configured scene (--stream FILE|- for packets)\n"
    "  assemble FILE|-      packet stream -> FITS (SCI, ERR, DQ, RESULTANTS)\n"
    "  record --rates FILE  write the scene's rate rows to a replay file\n"
    "  catalog [--seed N]   the synthetic field of that seed -> DIR/synthetic_{galaxies,stars}.fits\n"
    "  stamp --id ID        one catalog object's stamp (PSF, pixel, e-/s) -> DIR/stamp_ID.fits\n"
    "  psf --filter F --sca N --out F   a Roman PSF image (see wfisim psf --help)\n"
    "  coadd --center RA,DEC --size NX,NY --out F PRODUCT...   drizzle products of one\n"
    "                       filter onto a TAN grid (see wfisim coadd --help; docs/ANALYSIS.md)\n"
    "  diff --template COADD --epoch PRODUCT --out F   epoch minus template on its grid\n"
    "  accuracy psf|galaxy|scene|detector|all   error against CPU time of every rendering knob;\n"
    "                       detector: what leaving persistence out does to a star\n"
    "                       (docs/ACCURACY.md)\n"
    "  survey plan --out F  the deep-tier observation plan and its coverage map (docs/SURVEY.md)\n"
    "  survey run --plan F [--exposures A:B] [--scas 1,2,5-7] [--area RA,DEC,R] [--sne SNE.fits]\n"
    "             [--on-change refuse|redo] [--isolate]\n"
    "                       render every (exposure, SCA) of the range (whose SCA overlaps the\n"
    "                       circle of R deg); resumable: a product made from other inputs\n"
    "                       refuses the run (default) or is redone; with bin/wfisim-mpi under\n"
    "                       mpirun, on many processes; --isolate (always so under MPI): each\n"
    "                       item in a process of its own, a crash loses that item alone\n"
    "                       (docs/SURVEY.md)\n"
    "  survey index DIR     the index table of the products in DIR, from their headers\n"
    "  sn generate|lightcurves|lightcurve   supernova sample, truth light curves, one light\n"
    "                       curve (see wfisim sn --help; docs/SUPERNOVAE.md)\n"
    "  detect IMAGE --out CAT.fits   objects of an image (SEP: SExtractor's background, filter,\n"
    "                       deblending, aperture and Kron fluxes), see wfisim detect --help\n"
    "  hosts --out DIR LIST   SN hosts by nearest separation and by d_DLR against the truth,\n"
    "                       by redshift (see wfisim hosts --help; docs/ANALYSIS.md)\n"
    "  config doc           print the reference of every configuration key (docs/CONFIG.md)\n"
    "  config check FILE    load a configuration file and report the first problem\n"
    "\n"
    "options of the rendering commands:\n"
    "  --out DIR            output directory [out]           --seed N     noise seed [1]\n"
    "  --tile-rows N        rows per tile [64]               --threads N  readout threads [1]\n"
    "  --mode ramp|single   up the ramp or GalSim single frame [ramp]\n"
    "  --sampling per-read|direct|moments   how resultants are drawn [per-read]\n"
    "  --config FILE        YAML configuration (see docs/CONFIG.md)\n"
    "  --set KEY=VALUE      override one configuration key (repeatable)\n"
    "  --stream FILE|-      write the packet stream instead of FITS\n"
    "  --replay FILE        take the scene from a rate recording\n"
    "  --ra D --dec D --pa D --sca N --filter F --mjd M --exptime S\n"
    "                       pointing (PA as galsim.roman.getWCS), SCA, filter, mid-time, and\n"
    "                       the single-frame exposure time (ramp mode: the MA table's)\n"
    "  --catalog FILE [--stars FILE]   draw these catalogs (FITS or CSV, or a GalSim benchmark scene,\n"
    "                       recognised by its columns; docs/CATALOGS.md)\n"
    "  --data DIR           Roman data directory (default $WFISIM_DATA; none: built-ins)\n"
    "  --quiet              no progress output\n";

/* The exit status of a failure: 2 for bad input, 1 otherwise. */
static int exit_code(wf_status st)
{
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

static int fail(const char *what, wf_status st)
{
    fprintf(stderr, "wfisim: %s: %s\n", what, wf_error_message()[0] ? wf_error_message() : wf_status_name(st));
    return exit_code(st);
}

typedef struct cli {
    wf_config cfg;
    wf_clock clock;
    const char *stream;
    const char *replay;
    const char *rates;
    const char *positional;
    const char *id;
    const char *plan, *exposures, *scas, *sne, *model, *area, *on_change;
    int ma_table_given;
    int isolate;
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
        if (!strcmp(a, "--ma-table")) c->ma_table_given = 1;
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
            if (val && !strncmp(val, "readout.ma_table=", 17)) c->ma_table_given = 1;
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
        else if (!strcmp(a, "--plan") && val) { c->plan = val; i++; }
        else if (!strcmp(a, "--exposures") && val) { c->exposures = val; i++; }
        else if (!strcmp(a, "--scas") && val) { c->scas = val; i++; }
        else if (!strcmp(a, "--sne") && val) { c->sne = val; i++; }
        else if (!strcmp(a, "--model") && val) { c->model = val; i++; }
        else if (!strcmp(a, "--area") && val) { c->area = val; i++; }
        else if (!strcmp(a, "--on-change") && val) { c->on_change = val; i++; }
        else if (!strcmp(a, "--isolate")) c->isolate = 1;
        else if (a[0] == '-' && a[1] == '-') {
            fprintf(stderr, "wfisim: unknown option '%s' (see wfisim --help)\n", a);
            return 2;
        } else if (!c->positional) c->positional = a;
        else { fprintf(stderr, "wfisim: unexpected argument '%s'\n", a); return 2; }
    }
    if ((st = wf_config_finish(&c->cfg, &c->clock))) return fail("config", st);
    wf_fitsdisk_uncached(c->cfg.uncached_writes);
    return 0;
}

/* The SN sample of --sne with its model (--model, else the SALT3 model in the data folder). */
static wf_status open_injector(const cli *c, wf_sn_injector **inj, char *model, size_t cap)
{
    *inj = NULL;
    if (!c->sne) return WF_OK;
    if (c->model) snprintf(model, cap, "%s", c->model);
    else if (c->cfg.data_dir[0]) snprintf(model, cap, "%s/salt3/salt3-k21", c->cfg.data_dir);
    else return wf_error(WF_ERR_INPUT, "--sne needs the SALT model: give --model DIR or a data folder (--data)");
    return wf_sn_injector_open(c->sne, model, c->cfg.data_dir, inj);
}

static int run_exposure(cli *c, int demo)
{
    wf_pipeline_job job;
    memset(&job, 0, sizeof job);
    job.cfg = &c->cfg;
    job.clock = &c->clock;
    job.stream = c->stream;
    job.replay = c->replay;
    job.version = version;
    char model[WF_PATH_MAX + 32];
    wf_status st = open_injector(c, &job.injector, model, sizeof model);
    /* a scene cache named (auto is survey run's alone): its digests computed once */
    if (!st && strcmp(c->cfg.scene_cache, "auto") && strcmp(c->cfg.scene_cache, "none") && !c->replay &&
        !(st = wf_digest_cache_create(&job.digests)))
        st = wf_plane_cache_open(c->cfg.scene_cache, c->cfg.scene_cache_gib * 1073741824.0, &job.planes);
    if (!st) st = wf_pipeline_expose(&job);
    wf_plane_cache_close(job.planes);
    wf_digest_cache_free(job.digests);
    wf_sn_injector_free(job.injector);
    return st ? fail(demo ? "demo" : "expose", st) : 0;
}

static int cmd_assemble(cli *c)
{
    if (!c->positional) { fprintf(stderr, "wfisim assemble: give a stream file or '-'\n"); return 2; }
    FILE *in = strcmp(c->positional, "-") ? fopen(c->positional, "rb") : stdin;
    if (!in) { wf_error(WF_ERR_IO, "%s: cannot open", c->positional); return fail("assemble", WF_ERR_IO); }
    char made[WF_PATH_MAX];
    wf_status st = wf_file_make_dir_noting(c->cfg.out_dir, made);
    wf_assemble_options opt;
    wf_pipeline_assemble_options(&c->cfg, &opt);
    char path[WF_PATH_MAX] = "";
    if (!st) st = wf_assemble_stream(in, c->positional, &opt, path, sizeof path);
    if (in != stdin) fclose(in);
    if (st) wf_file_unmake_dir(c->cfg.out_dir, made); /* a damaged stream leaves no empty folder */
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
    wf_scene_inputs in;
    wf_scene *scene = NULL;
    double *pix = NULL;
    wf_status st = wf_pipeline_load_catalogs(cfg, &in);
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
    ss.psf_nlambda = cfg->psf_nlambda;
    ss.jitter = cfg->psf_jitter;
    ss.diffusion = cfg->psf_diffusion;
    ss.bright_mag = cfg->psf_bright_mag;
    ss.flux_fraction = cfg->flux_fraction;
    ss.core_radius = cfg->psf_core_radius;
    ss.core_levels = cfg->psf_core_levels;
    ss.sky_on = 0;
    if (!st) st = wf_scene_create(&ss, in.have_gal && in.gal.n ? &in.gal : NULL, in.have_stars && in.stars.n ? &in.stars : NULL, &scene);
    if (!st && wf_scene_object_count(scene) == 0)
        st = wf_error(WF_ERR_INPUT, "object %lld does not reach SCA %u of this pointing", id, cfg->ro.sca);
    wf_scene_object info;
    int x0 = 0, y0 = 0, nx = 0, ny = 0;
    if (!st) st = wf_scene_draw_object(scene, 0, &info, &x0, &y0, &nx, &ny, &pix);
    /* the object alone, clipped at zero as the renderer clips its sum (the draws keep their
     * ringing, ~1e-7 of the flux with the sky off) */
    for (size_t i = 0; !st && i < (size_t)nx * ny; i++)
        if (pix[i] < 0.0) pix[i] = 0.0;
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/stamp_%lld.fits", cfg->out_dir, id);
    fitsfile *f = NULL;
    char made[WF_PATH_MAX] = "";
    if (!st) st = wf_file_make_dir_noting(cfg->out_dir, made);
    if (!st) st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (!st) {
        int status = 0;
        long naxes[2] = {nx, ny};
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
        fits_write_key_dbl(f, "CORERAD", cfg->psf_core_radius, 6, "[arcsec] PSF core radius (0: no split)", &status);
        fits_write_key_lng(f, "CORELEV", cfg->psf_core_levels, "PSF cores, radius halved at each", &status);
        fits_write_key_str(f, "BUNIT", "electron/s", "", &status);
        long first[2] = {1, 1};
        fits_write_pix(f, TDOUBLE, first, (long long)nx * ny, pix, &status);
        st = wf_fits_finish(f, tmp, path, wf_fits_error(status, tmp, "writing the stamp"));
    }
    if (st) wf_file_unmake_dir(cfg->out_dir, made);
    if (!st && !cfg->quiet) fprintf(stderr, "wfisim: wrote %s (%d x %d, %s %lld, %.4g e-/s)\n", path, nx, ny,
                                    info.kind ? "star" : "galaxy", info.id, info.flux);
    free(pix);
    wf_scene_destroy(scene);
    wf_pipeline_inputs_free(&in);
    return st ? fail("stamp", st) : 0;
}

static int cmd_survey_run(cli *c)
{
    if (!c->plan) { fprintf(stderr, "wfisim survey run: give --plan plan.fits (from wfisim survey plan)\n"); return 2; }
    wf_survey_run_options opt;
    memset(&opt, 0, sizeof opt);
    opt.plan_path = c->plan;
    opt.first = 0;
    opt.last = -1;
    opt.ma_table_given = c->ma_table_given;
    opt.version = version;
    if (c->on_change && strcmp(c->on_change, "refuse") && strcmp(c->on_change, "redo")) {
        fprintf(stderr, "wfisim survey run: --on-change '%s': expected refuse or redo\n", c->on_change);
        return 2;
    }
    opt.redo_changed = c->on_change && !strcmp(c->on_change, "redo");
    opt.isolate = c->isolate;
    wf_status st = WF_OK;
    if (c->exposures) st = wf_survey_parse_range(c->exposures, &opt.first, &opt.last);
    if (!st && c->scas) st = wf_survey_parse_scas(c->scas, opt.scas, &opt.nscas);
    if (!st && c->area) st = wf_survey_parse_area(c->area, &opt);
    if (st) return fail("survey run", st);
    if (c->cfg.scene_kind == 2 || c->replay || c->stream) {
        fprintf(stderr, "wfisim survey run: the survey draws a scene (scene.kind synthetic, catalog or galsim); no --replay or --stream\n");
        return 2;
    }
    char model[WF_PATH_MAX + 32];
    if ((st = open_injector(c, &opt.sne, model, sizeof model))) return fail("survey run", st);
    opt.sne_path = c->sne;
    opt.sne_model = model;
    wf_survey_run_stats stats;
#ifdef WF_MPI
    st = wf_survey_run_mpi(&c->cfg, &opt, &stats);
#else
    st = wf_survey_run(&c->cfg, &opt, &stats);
#endif
    wf_sn_injector_free(opt.sne);
    /* silent: another rank (rank 0) says why and gives the job its status. Such a rank ends
     * with 0: a non-zero exit makes mpirun abort the job, which could kill rank 0 before its
     * message is out (seen on a fresh machine: the refusal never printed). */
    if (st) return stats.silent ? 0 : fail("survey run", st);
    if (!c->cfg.quiet && !stats.silent)
        fprintf(stderr, "wfisim survey: %ld products rendered (%ld replacing damaged ones, %ld made from other inputs), "
                "%ld already done; %ld supernova images%s\n", stats.rendered, stats.redone, stats.changed,
                stats.skipped, stats.sne_drawn, c->area ? "; SCAs outside --area not made" : "");
    if (!c->cfg.quiet && !stats.silent && stats.rendered)
        fprintf(stderr, "wfisim survey: PSFs: %ld built (the items of an SCA and filter share one); static "
                "scenes: %ld of the %ld products' from the scene cache\n", stats.psf_built, stats.planes_found,
                stats.rendered);
    if (!stats.silent && stats.planes_not_kept) /* not a failure, but the user must know: a warning */
        fprintf(stderr, "wfisim survey: warning: the scene cache could not keep the scenes of %ld products (%s); "
                "the products are whole, later exposures of those scenes draw them again\n", stats.planes_not_kept,
                stats.planes_reason[0] ? stats.planes_reason : "the reason is in the processes that drew them");
    if (!c->cfg.quiet && !stats.silent && c->cfg.ro.persist.on)
        fprintf(stderr, "wfisim survey: persistence histories: %ld earlier exposures, %ld of them drawn\n",
                stats.hist_used, stats.hist_drawn);
    return 0;
}

/* The synthetic field of a seed as catalog files (what the synthetic scene draws from, cell
 * by cell): DIR/synthetic_galaxies.fits and DIR/synthetic_stars.fits. */
static int cmd_catalog(cli *c)
{
    wf_synth_config sc;
    wf_synth *syn = NULL;
    wf_catalog gal, stars;
    int have = 0;
    wf_status st0 = wf_config_synth(&c->cfg, &sc);
    char gpath[WF_PATH_MAX + 64], spath[WF_PATH_MAX + 64];
    snprintf(gpath, sizeof gpath, "%s/synthetic_galaxies.fits", c->cfg.out_dir);
    snprintf(spath, sizeof spath, "%s/synthetic_stars.fits", c->cfg.out_dir);
    char made[WF_PATH_MAX];
    wf_status st = st0 ? st0 : wf_file_make_dir_noting(c->cfg.out_dir, made);
    if (!st) st = wf_synth_create(&sc, &syn);
    if (!st && !(st = wf_synth_generate_all(syn, &gal, &stars))) have = 1;
    if (!st) st = wf_catalog_write_fits(gpath, &gal);
    if (!st) st = wf_catalog_write_fits(spath, &stars);
    if (!st && !c->cfg.quiet)
        fprintf(stderr, "wfisim: wrote %s (%zu galaxies) and %s (%zu stars), seed %llu\n", gpath, gal.n, spath,
                stars.n, (unsigned long long)sc.seed);
    if (have) {
        wf_catalog_free(&gal);
        wf_catalog_free(&stars);
    }
    wf_synth_free(syn);
    if (st) wf_file_unmake_dir(c->cfg.out_dir, made);
    return st ? fail("catalog", st) : 0;
}

static int cmd_record(cli *c)
{
    if (!c->rates) { fprintf(stderr, "wfisim record: give --rates FILE\n"); return 2; }
    wf_scene_grid grid;
    wf_scene_source src;
    wf_pipeline_grid(&c->cfg, &grid);
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
    snprintf(version, sizeof version, "%s+src.%s", WFISIM_VERSION, wf_digest_source());
    if (!strcmp(cmd, "--version")) { printf("wfisim %s\n", version); return 0; }
    if (!strcmp(cmd, "survey") && argc >= 3 && !strcmp(argv[2], "run")) {
        cli c;
        int rc = parse(argc - 3, argv + 3, &c);
        return rc ? rc : cmd_survey_run(&c);
    }
    if (!strcmp(cmd, "survey")) return wf_cmd_survey(argc - 2, argv + 2);
    if (!strcmp(cmd, "psf")) return wf_cmd_psf(argc - 2, argv + 2);
    if (!strcmp(cmd, "coadd")) return wf_cmd_coadd(argc - 2, argv + 2);
    if (!strcmp(cmd, "diff")) return wf_cmd_diff(argc - 2, argv + 2);
    if (!strcmp(cmd, "accuracy")) return wf_cmd_accuracy(argc - 1, argv + 1);
    if (!strcmp(cmd, "sn")) return wf_cmd_sn(argc - 2, argv + 2);
    if (!strcmp(cmd, "detect")) return wf_cmd_detect(argc - 2, argv + 2);
    if (!strcmp(cmd, "efficiency")) return wf_cmd_efficiency(argc - 2, argv + 2);
    if (!strcmp(cmd, "hosts")) return wf_cmd_hosts(argc - 2, argv + 2);
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
    if (!strcmp(cmd, "catalog")) return cmd_catalog(&c);
    if (!strcmp(cmd, "stamp")) return cmd_stamp(&c);
    fprintf(stderr, "wfisim: unknown command '%s'\n\n%s", cmd, usage_text);
    return 2;
}
