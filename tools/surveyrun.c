#include "tools/surveyrun.h"

#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hal/clock.h"
#include "sim/fitsout.h"
#include "sim/skyindex.h"
#include "sim/survey.h"
#include "tools/pipeline.h"
#include "tools/surveyrelease.h"

wf_status wf_survey_parse_range(const char *text, long *first, long *last)
{
    char *end;
    long a = strtol(text, &end, 10);
    if (end == text || a < 0) return wf_error(WF_ERR_INPUT, "--exposures '%s': expected A:B, A: or A (EXPIDs >= 0)", text);
    if (*end == '\0') { *first = *last = a; return WF_OK; }
    if (*end != ':') return wf_error(WF_ERR_INPUT, "--exposures '%s': expected A:B, A: or A", text);
    const char *b = end + 1;
    if (*b == '\0') { *first = a; *last = -1; return WF_OK; }
    long v = strtol(b, &end, 10);
    if (end == b || *end || v < a) return wf_error(WF_ERR_INPUT, "--exposures '%s': B must be an integer >= A", text);
    *first = a;
    *last = v;
    return WF_OK;
}

wf_status wf_survey_parse_scas(const char *text, int *scas, int *n)
{
    int seen[WF_NSCA + 1] = {0};
    *n = 0;
    const char *p = text;
    while (*p) {
        char *end;
        long a = strtol(p, &end, 10), b = a;
        if (end == p) return wf_error(WF_ERR_INPUT, "--scas '%s': expected a list like 1,2,5-7", text);
        if (*end == '-') {
            const char *q = end + 1;
            b = strtol(q, &end, 10);
            if (end == q) return wf_error(WF_ERR_INPUT, "--scas '%s': expected a list like 1,2,5-7", text);
        }
        if (a < 1 || b > WF_NSCA || b < a) return wf_error(WF_ERR_RANGE, "--scas '%s': SCAs are 1..18", text);
        for (long s = a; s <= b; s++) {
            if (seen[s]) return wf_error(WF_ERR_INPUT, "--scas '%s': SCA %ld given twice", text, s);
            seen[s] = 1;
            scas[(*n)++] = (int)s;
        }
        if (*end == ',') end++;
        else if (*end) return wf_error(WF_ERR_INPUT, "--scas '%s': unexpected '%c'", text, *end);
        p = end;
    }
    if (!*n) return wf_error(WF_ERR_INPUT, "--scas is empty");
    return WF_OK;
}

int wf_survey_product_ok(const char *path)
{
    /* Whether it is missing, damaged or cut short, a product that is not whole is redone. */
    return wf_fits_verify_checksums(path, 0) == WF_OK;
}

/* The rows of the plan with EXPID in [first, last] (last < 0: to the end), in file order. */
static wf_status read_plan(const char *path, long first, long last, wf_survey_row **out, size_t *n)
{
    wf_status st = wf_survey_read_plan(path, out, n);
    if (st) return st;
    wf_survey_row *rows = *out;
    size_t k = 0;
    for (size_t i = 0; i < *n; i++)
        if (rows[i].expid >= first && (last < 0 || rows[i].expid <= last)) rows[k++] = rows[i];
    *n = k;
    return WF_OK;
}

/* The built-in Rev F table whose duration is nearest t seconds at this frame time. */
static wf_status nearest_table(double frame_time, double t, char *name, size_t cap)
{
    static const char *tables[] = {"4", "6", "11"};
    double best = INFINITY;
    for (int k = 0; k < 3; k++) {
        wf_clock c = {0};
        c.frame_time = frame_time;
        wf_status st = wf_ma_builtin(tables[k], &c.ma);
        if (st) return st;
        double d = fabs(wf_clock_exposure_time(&c) - t);
        if (d < best) {
            best = d;
            snprintf(name, cap, "%s", tables[k]);
        }
    }
    return WF_OK;
}

static wf_status configure(const wf_config *base, const wf_survey_run_options *opt, const wf_survey_row *x,
                           int sca, wf_config *cfg, wf_clock *clock)
{
    *cfg = *base;
    char buf[64];
    cfg->ra = x->ra;
    cfg->dec = x->dec;
    cfg->pa = x->pa;
    cfg->mjd = x->mjd_mid;
    cfg->ro.exposure = (uint32_t)x->expid;
    cfg->ro.sca = (uint32_t)sca;
    snprintf(buf, sizeof buf, "exposure.filter=%s", x->filter);
    wf_status st = wf_config_set(cfg, buf, opt->plan_path);
    if (st) return st;
    cfg->ro.exptime = x->exptime;
    /* products a survey can keep: tile-compressed unless asked otherwise (docs/SURVEY.md) */
    if (cfg->products.compress == WF_COMPRESS_AUTO) cfg->products.compress = WF_COMPRESS_RICE;
    if (!opt->ma_table_given) {
        char name[8];
        if ((st = nearest_table(cfg->frame_time, x->exptime, name, sizeof name))) return st;
        snprintf(cfg->ma_table, sizeof cfg->ma_table, "%s", name);
    }
    return wf_config_finish(cfg, clock);
}

/* The survey-level record of a run, DIR/survey_run.txt: the plan (and its checksum), the
 * catalogs the scenes were drawn from and the SN sample, so the products can be traced to
 * their inputs. Rewritten (temporary file, rename) at the end of every run. */
static wf_status write_manifest(const wf_config *cfg, const wf_survey_run_options *opt, const wf_survey_row *rows,
                                size_t nrows, const wf_survey_run_stats *stats, const char *note)
{
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/survey_run.txt", cfg->out_dir);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    char datasum[FLEN_VALUE] = "";
    fitsfile *f;
    int status = 0;
    if (!fits_open_diskfile(&f, opt->plan_path, READONLY, &status)) {
        fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
        fits_read_key_str(f, "DATASUM", datasum, NULL, &status);
        int cs = 0;
        fits_close_file(f, &cs);
    }
    static const char *const kinds[] = {"synthetic", "catalog", "grid", "galsim"};
    FILE *out = fopen(tmp, "w");
    if (!out) return wf_error(WF_ERR_IO, "%s: cannot create", tmp);
    fprintf(out, "# wfisim survey run: the inputs of the products in this folder\n");
    fprintf(out, "wfisim = %s\n", opt->version ? opt->version : "?");
    fprintf(out, "plan = %s\nplan.datasum = %s\n", opt->plan_path, datasum);
    fprintf(out, "exposures = %d:%d\n", rows[0].expid, rows[nrows - 1].expid);
    fprintf(out, "scas =");
    for (int k = 0; k < (opt->nscas ? opt->nscas : WF_NSCA); k++) fprintf(out, " %d", opt->nscas ? opt->scas[k] : k + 1);
    fprintf(out, "\nseed = %llu\nmode = %s\nsampling = %s\n", (unsigned long long)cfg->seed,
            cfg->ro.mode == WF_MODE_SINGLE ? "single" : "ramp", cfg->ro.sampling == WF_SAMPLE_DIRECT ? "direct" : "per-read");
    fprintf(out, "scene.kind = %s\n", kinds[cfg->scene_kind]);
    if (cfg->scene_kind == 0)
        fprintf(out, "catalogs = synthetic field of seed %llu (`wfisim catalog --seed %llu` writes it)\n",
                (unsigned long long)cfg->seed, (unsigned long long)cfg->seed);
    else
        fprintf(out, "scene.catalog = %s\nscene.stars = %s\n", cfg->catalog, cfg->stars);
    fprintf(out, "sne = %s\n", opt->sne_path ? opt->sne_path : "(none)");
    if (opt->area)
        fprintf(out, "area = %.10g,%.10g,%.10g (RA, Dec, radius, deg: the SCAs whose footprint overlaps it)\n",
                opt->area_ra, opt->area_dec, opt->area_radius);
    fprintf(out, "index = survey_index.fits, survey_index.csv\n");
    fprintf(out, "products.rendered = %ld\nproducts.skipped = %ld\nproducts.redone = %ld\n", stats->rendered,
            stats->skipped, stats->redone);
    if (opt->area) fprintf(out, "products.outside_area = %ld\n", stats->outside);
    fputs(note, out);
    return wf_survey_text_commit(out, tmp, path);
}

wf_status wf_survey_parse_area(const char *text, wf_survey_run_options *opt)
{
    double v[3];
    const char *p = text;
    for (int k = 0; k < 3; k++) {
        char *end;
        v[k] = strtod(p, &end);
        if (end == p || !isfinite(v[k]) || (k < 2 ? *end != ',' : *end != '\0'))
            return wf_error(WF_ERR_INPUT, "--area '%s': expected RA,DEC,RADIUS in degrees", text);
        p = end + 1;
    }
    if (v[1] < -90.0 || v[1] > 90.0 || !(v[2] > 0.0) || !(v[2] < 90.0))
        return wf_error(WF_ERR_RANGE, "--area '%s': DEC must be in [-90, 90] and RADIUS in (0, 90) degrees", text);
    opt->area = 1;
    opt->area_ra = fmod(fmod(v[0], 360.0) + 360.0, 360.0);
    opt->area_dec = v[1];
    opt->area_radius = v[2];
    return WF_OK;
}

typedef struct wf_survey_item { int row, sca; } wf_survey_item;

struct wf_survey_ctx {
    const wf_config *base;
    const wf_survey_run_options *opt;
    wf_survey_row *rows;
    size_t nrows;
    wf_survey_item *items;
    size_t nitems;
    long outside;
    wf_config *cfg; /* the item's configuration (large: on the heap) */
    wf_pipeline_job *job;
};

void wf_survey_free(wf_survey_ctx *ctx)
{
    if (!ctx) return;
    free(ctx->rows);
    free(ctx->items);
    free(ctx->cfg);
    free(ctx->job);
    free(ctx);
}

/* Whether an SCA's footprint at this pointing overlaps the circle of --area: the footprint
 * grown by the radius holds the circle's centre (sim/skyindex.h, exact on the sphere). */
static wf_status in_area(const wf_config *cfg, const wf_survey_run_options *opt, int *inside)
{
    wf_skyregion reg;
    wf_status st = wf_pipeline_sca_footprint(cfg, opt->area_radius * 3600.0, &reg);
    if (!st) *inside = wf_skyindex_contains(&reg, opt->area_ra, opt->area_dec);
    return st;
}

wf_status wf_survey_begin(const wf_config *base, const wf_survey_run_options *opt, wf_survey_ctx **out,
                          size_t *nitems)
{
    *out = NULL;
    *nitems = 0;
    wf_survey_ctx *ctx = calloc(1, sizeof *ctx);
    if (!ctx) return wf_error(WF_ERR_NOMEM, "out of memory");
    ctx->base = base;
    ctx->opt = opt;
    wf_status st = read_plan(opt->plan_path, opt->first, opt->last, &ctx->rows, &ctx->nrows);
    if (st) { free(ctx); return st; }
    if (!ctx->nrows) st = wf_error(WF_ERR_INPUT, "%s: no exposure in the range asked for", opt->plan_path);
    int nscas = opt->nscas ? opt->nscas : WF_NSCA;
    ctx->cfg = malloc(sizeof *ctx->cfg);
    ctx->job = malloc(sizeof *ctx->job);
    ctx->items = malloc((ctx->nrows ? ctx->nrows : 1) * (size_t)nscas * sizeof *ctx->items);
    if (!st && (!ctx->cfg || !ctx->job || !ctx->items)) st = wf_error(WF_ERR_NOMEM, "out of memory");
    for (size_t i = 0; i < ctx->nrows && !st; i++)
        for (int k = 0; k < nscas && !st; k++) {
            int sca = opt->nscas ? opt->scas[k] : k + 1, inside = 1;
            if (opt->area) {
                wf_clock clock;
                if (!(st = configure(base, opt, &ctx->rows[i], sca, ctx->cfg, &clock))) st = in_area(ctx->cfg, opt, &inside);
            }
            if (!inside) ctx->outside++;
            else ctx->items[ctx->nitems++] = (wf_survey_item){(int)i, sca};
        }
    if (!st && !ctx->nitems) st = wf_error(WF_ERR_INPUT, "--area: no SCA of the exposures asked for overlaps it");
    if (!st) st = wf_pipeline_make_dir(base->out_dir);
    if (st) { wf_survey_free(ctx); return st; }
    *out = ctx;
    *nitems = ctx->nitems;
    return WF_OK;
}

void wf_survey_item_name(const wf_survey_ctx *ctx, size_t i, char *buf, size_t cap)
{
    snprintf(buf, cap, "exposure %d SCA %d", ctx->rows[ctx->items[i].row].expid, ctx->items[i].sca);
}

wf_status wf_survey_make_item(wf_survey_ctx *ctx, size_t i, wf_survey_item_result *res)
{
    memset(res, 0, sizeof *res);
    const wf_survey_row *x = &ctx->rows[ctx->items[i].row];
    wf_config *cfg = ctx->cfg;
    wf_clock clock;
    wf_status st = configure(ctx->base, ctx->opt, x, ctx->items[i].sca, cfg, &clock);
    if (st) return st;
    char image[WF_PATH_MAX + 64], truth[WF_PATH_MAX + 64];
    wf_pipeline_paths(cfg->out_dir, cfg->ro.exposure, cfg->ro.sca, image, truth, sizeof image);
    FILE *probe = fopen(image, "rb");
    int existed = probe != NULL;
    if (probe) fclose(probe);
    if (!existed || !wf_survey_product_ok(image) || !wf_survey_product_ok(truth)) {
        char extra[1024];
        snprintf(extra, sizeof extra,
                 "hdr.VISIT = %d / 0-based visit of the plan\n"
                 "hdr.ORIENT = %d / 0-based orient of the plan\n"
                 "hdr.POINTING = %d / 0-based pointing along the forward snake\n"
                 "hdr.PASS = %d / 0-based filter pass of the visit\n"
                 "hdr.PLANEXPT = %.3f / [s] planned exposure time\n",
                 x->visit, x->orient, x->pointing, x->pass, x->exptime);
        wf_pipeline_job *job = ctx->job;
        memset(job, 0, sizeof *job);
        job->cfg = cfg;
        job->clock = &clock;
        job->meta_extra = extra;
        job->injector = ctx->opt->sne;
        job->version = ctx->opt->version;
        cfg->quiet = 1;
        if ((st = wf_pipeline_expose(job))) {
            char msg[1024];
            snprintf(msg, sizeof msg, "%s", wf_error_message());
            return wf_error(st, "exposure %d SCA %d: %s", x->expid, ctx->items[i].sca, msg);
        }
        res->made = 1;
        res->redone = existed;
        res->sne = (int64_t)job->nsne_drawn;
    }
    const char *name = strrchr(image, '/');
    return wf_survey_index_read(cfg->out_dir, name ? name + 1 : image, &res->row);
}

wf_status wf_survey_end(wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_survey_run_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    stats->outside = ctx->outside;
    wf_survey_index_row *rows = malloc(ctx->nitems * sizeof *rows);
    if (!rows) return wf_error(WF_ERR_NOMEM, "out of memory for the index");
    for (size_t i = 0; i < ctx->nitems; i++) {
        if (res[i].made) stats->rendered++;
        else stats->skipped++;
        stats->redone += res[i].redone;
        stats->sne_drawn += (long)res[i].sne;
        rows[i] = res[i].row;
    }
    const wf_survey_run_options *opt = ctx->opt;
    wf_status st = wf_survey_index_write(ctx->base->out_dir, rows, ctx->nitems);
    char note[1024] = "";
    double centre[2] = {opt->area_ra, opt->area_dec};
    if (!st && opt->sne_path)
        st = wf_survey_write_release(ctx->base, opt->plan_path, opt->sne_path, opt->sne_model, opt->area ? centre : NULL,
                                     rows, ctx->nitems, note, sizeof note);
    free(rows);
    if (!st) st = write_manifest(ctx->base, opt, ctx->rows, ctx->nrows, stats, note);
    return st;
}

wf_status wf_survey_run(const wf_config *base, const wf_survey_run_options *opt, wf_survey_run_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    wf_survey_ctx *ctx;
    size_t n;
    wf_status st = wf_survey_begin(base, opt, &ctx, &n);
    if (st) return st;
    wf_survey_item_result *res = calloc(n, sizeof *res);
    if (!res) st = wf_error(WF_ERR_NOMEM, "out of memory");
    time_t t0 = time(NULL);
    for (size_t i = 0; i < n && !st; i++) {
        if ((st = wf_survey_make_item(ctx, i, &res[i]))) break;
        if (!base->quiet && res[i].made) {
            const wf_survey_row *x = &ctx->rows[ctx->items[i].row];
            fprintf(stderr, "wfisim survey: [%zu/%zu] exposure %d SCA %d %s MJD %.5f%s (%.0f s)\n", i + 1, n,
                    x->expid, ctx->items[i].sca, x->filter, x->mjd_mid,
                    res[i].redone ? " (damaged product redone)" : "", difftime(time(NULL), t0));
        }
    }
    if (!st) st = wf_survey_end(ctx, res, stats);
    free(res);
    wf_survey_free(ctx);
    return st;
}
