#include "tools/surveyrun.h"

#include "sim/draw/plane_cache.h"

#include <dirent.h>
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "hal/file.h"
#include "hal/clock.h"
#include "sim/draw/scene_psf.h"
#include "sim/fits/fitsout.h"
#include "sim/survey/skyindex.h"
#include "sim/survey/survey.h"
#include "tools/digest.h"
#include "tools/isolate.h"
#include "tools/persist.h"
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

/* The rows of the whole plan with EXPID in [first, last] (last < 0: to the end), in file order,
 * copied (the plan is read once per run), and each one's index in plan. */
static wf_status select_rows(const wf_survey_row *plan, size_t nplan, long first, long last, wf_survey_row **out,
                             size_t **full, size_t *n)
{
    *n = 0;
    *out = malloc((nplan ? nplan : 1) * sizeof **out);
    *full = malloc((nplan ? nplan : 1) * sizeof **full);
    if (!*out || !*full) return wf_error(WF_ERR_NOMEM, "out of memory for the plan");
    for (size_t i = 0; i < nplan; i++)
        if (plan[i].expid >= first && (last < 0 || plan[i].expid <= last)) {
            (*out)[*n] = plan[i];
            (*full)[(*n)++] = i;
        }
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

/* The primary-header lines a survey product adds: where it sits in the plan. */
static void plan_extra(const wf_survey_row *x, char *extra, size_t cap)
{
    snprintf(extra, cap,
             "hdr.VISIT = %d / 0-based visit of the plan\n"
             "hdr.ORIENT = %d / 0-based orient of the plan\n"
             "hdr.POINTING = %d / 0-based pointing along the forward snake\n"
             "hdr.PASS = %d / 0-based filter pass of the visit\n"
             "hdr.PLANEXPT = %.3f / [s] planned exposure time\n",
             x->visit, x->orient, x->pointing, x->pass, x->exptime);
}

/* One product: its configuration, header lines, names and (when asked) input digest. */
typedef struct product {
    wf_config cfg;
    wf_clock clock;
    char extra[1024];
    char image[WF_PATH_MAX + 64], truth[WF_PATH_MAX + 64];
    wf_digest digest;
} product;

/* Where an item's persistence history comes from: the plan's earlier exposures of its SCA. */
typedef struct history {
    int n;
    size_t row[WF_PERSIST_DEPTH_MAX]; /* in the whole plan, most recent first */
    double dt[WF_PERSIST_DEPTH_MAX];  /* s from its end to this exposure's start */
} history;

/* The earlier rows of the whole plan (before row `full`) whose exposure of the SCA ended at
 * most detector.persistence.window before this one's start, the most recent first, at most
 * detector.persistence.depth: from the plan alone, so a run that starts mid-plan (--exposures,
 * another rank, a resume) finds the same ones. Their end is their start plus the exposure
 * time they are read for (the MA table's last read), at the latest one frame before this
 * exposure begins. */
static wf_status history_rows(const wf_config *base, const wf_survey_run_options *opt, const wf_survey_row *plan,
                              size_t full, int sca, wf_config *scratch, history *h)
{
    h->n = 0;
    if (!base->ro.persist.on) return WF_OK;
    const wf_survey_row *x = &plan[full];
    for (size_t k = full; k-- > 0 && h->n < base->persist.depth;) {
        wf_clock clock;
        wf_status st = configure(base, opt, &plan[k], sca, scratch, &clock);
        if (st) return st;
        double t = scratch->ro.mode == WF_MODE_SINGLE ? scratch->ro.exptime : wf_clock_exposure_time(&clock);
        double dt = (x->mjd_start - plan[k].mjd_start) * 86400.0 - t;
        /* An exposure cannot begin before the one before it was read out. Where the plan's
         * slot is shorter than the read pattern (F184's 900 s read by MA table 11 for 977 s,
         * 50 s of slew before the next: 27 s too short; or any --ma-table longer than the
         * exposures), the later one begins one frame (its reset) after the earlier's last read;
         * its MJD stays the plan's. Each earlier row is moved on its own, not by the overruns
         * of the rows after it: with slots far shorter than the table several of them end one
         * frame before, an approximation of a schedule the plan does not describe. */
        const double gap = scratch->ro.mode == WF_MODE_SINGLE ? 0.0 : clock.frame_time;
        if (dt < gap) dt = gap;
        if (dt > base->persist.window) break;
        h->row[h->n] = k;
        h->dt[h->n++] = dt;
    }
    return WF_OK;
}

/* The history's exposures in the product's header (and so in its input digest: a plan whose
 * earlier rows changed remakes the product). */
static void history_extra(const wf_config *base, const wf_survey_row *plan, const history *h, char *extra, size_t cap)
{
    if (!base->ro.persist.on) return;
    size_t len = strlen(extra);
    len += (size_t)snprintf(extra + len, cap - len, "hdr.PERSISTN = %d / exposures in the persistence history\n", h->n);
    for (int j = 0; j < h->n && len < cap; j++)
        len += (size_t)snprintf(extra + len, cap - len, "hdr.PERSEX%d = %d / its EXPID; ended %.3f s before start\n",
                                j + 1, plan[h->row[j]].expid, h->dt[j]);
}

static wf_status prepare(const wf_survey_ctx *ctx, size_t item, wf_digest_cache *cache, product *p);

static wf_status prepare_row(const wf_config *base, const wf_survey_run_options *opt, const wf_survey_row *x, int sca,
                             wf_digest_cache *cache, product *p, const wf_survey_row *plan, const history *h)
{
    wf_status st = configure(base, opt, x, sca, &p->cfg, &p->clock);
    if (st) return st;
    plan_extra(x, p->extra, sizeof p->extra);
    history_extra(base, plan, h, p->extra, sizeof p->extra);
    wf_pipeline_paths(p->cfg.out_dir, p->cfg.ro.exposure, p->cfg.ro.sca, p->image, p->truth, sizeof p->image);
    if (!cache) return WF_OK; /* no digest asked for */
    wf_digest_inputs in = {&p->cfg, &p->clock, p->extra, NULL, opt->sne, NULL, 0, opt->version};
    return wf_digest_product(cache, &in, &p->digest);
}

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* Where an item's product stands before the run (the check's verdict). */
enum { P_UNCHECKED, P_MISSING, P_SAME, P_CHANGED, P_UNREADABLE };

typedef struct wf_survey_item { int row, sca; } wf_survey_item;

struct wf_survey_ctx {
    const wf_config *base;
    const wf_survey_run_options *opt;
    wf_survey_row *rows;
    size_t nrows;
    wf_survey_item *items;
    size_t nitems;
    long outside;
    wf_survey_row *plan;      /* the whole plan, whatever the range: the persistence history */
    size_t nplan;
    size_t *full;             /* per row of rows, its index in plan */
    wf_config *scratch;       /* an earlier exposure's configuration */
    history *hist;            /* per item, its persistence history's rows (from the plan, once) */
    wf_persist_cache *pcache; /* earlier exposures' bright pixels, for the next items */
    wf_scene_psf_cache *psfs; /* the last items' PSFs, for the next ones of their SCA and filter */
    wf_plane_cache *planes;   /* run.scene_cache, opened with the first item made (NULL: none) */
    int planes_tried;
    wf_status planes_st;      /* and why it could not be */
    char planes_msg[600];
    unsigned char *state;     /* per item, P_* */
    size_t todo;              /* items the check found to make (0: nothing will be written) */
    product *p;               /* the item's configuration and names (large: on the heap) */
    wf_pipeline_job *job;
    wf_digest_cache *cache;   /* file digests, computed once per process */
};

static wf_status prepare(const wf_survey_ctx *ctx, size_t item, wf_digest_cache *cache, product *p)
{
    const wf_survey_item *it = &ctx->items[item];
    return prepare_row(ctx->base, ctx->opt, &ctx->rows[it->row], it->sca, cache, p, ctx->plan, &ctx->hist[item]);
}

void wf_survey_free(wf_survey_ctx *ctx)
{
    if (!ctx) return;
    free(ctx->rows);
    free(ctx->plan);
    free(ctx->full);
    free(ctx->hist);
    free(ctx->scratch);
    wf_persist_cache_free(ctx->pcache);
    wf_scene_psf_cache_free(ctx->psfs);
    wf_plane_cache_close(ctx->planes);
    free(ctx->items);
    free(ctx->state);
    free(ctx->p);
    free(ctx->job);
    wf_digest_cache_free(ctx->cache);
    free(ctx);
}

static int key_cmp(const void *a, const void *b)
{
    long x = *(const long *)a, y = *(const long *)b;
    return (x > y) - (x < y);
}

/* The products of the folder that are not items of this run (other ranges, other SCAs,
 * outside --area), sorted by name so that the record does not depend on the file system's
 * order. *names is malloc'd, 32 bytes a name. */
static wf_status other_products(const wf_survey_ctx *ctx, char (**names)[32], size_t *n)
{
    *names = NULL;
    *n = 0;
    long *keys = malloc((ctx->nitems ? ctx->nitems : 1) * sizeof *keys);
    if (!keys) return wf_error(WF_ERR_NOMEM, "out of memory");
    for (size_t i = 0; i < ctx->nitems; i++) keys[i] = ctx->rows[ctx->items[i].row].expid * 100L + ctx->items[i].sca;
    qsort(keys, ctx->nitems, sizeof *keys, key_cmp);
    DIR *dir = opendir(ctx->base->out_dir);
    size_t cap = 0;
    wf_status st = WF_OK;
    for (struct dirent *e; dir && !st && (e = readdir(dir));) {
        unsigned expid, sca;
        int used = 0;
        if (strlen(e->d_name) >= 32 || sscanf(e->d_name, "wfisim_e%6u_sca%2u.fits%n", &expid, &sca, &used) != 2 ||
            e->d_name[used])
            continue;
        long key = (long)expid * 100L + (long)sca;
        if (bsearch(&key, keys, ctx->nitems, sizeof *keys, key_cmp)) continue;
        if (*n == cap) {
            size_t nc = cap ? 2 * cap : 64;
            char(*q)[32] = realloc(*names, nc * sizeof *q);
            if (!q) { st = wf_error(WF_ERR_NOMEM, "out of memory"); break; }
            *names = q;
            cap = nc;
        }
        snprintf((*names)[(*n)++], 32, "%s", e->d_name);
    }
    if (dir) closedir(dir);
    free(keys);
    if (!st && *n) qsort(*names, *n, sizeof **names, (int (*)(const void *, const void *))strcmp);
    if (st) { free(*names); *names = NULL; *n = 0; }
    return st;
}

/* The survey-level record of a run, DIR/survey_run.txt: the plan (and its checksum), the
 * catalogs the scenes were drawn from, the SN sample, the digests of the inputs, and every
 * product of the folder as it stands (its WFDIGEST, read back from its header), so that the
 * record never claims inputs that did not make a product. Written by one process through a
 * temporary file and a rename: with status "in progress" after the check, before the first
 * product is rendered (an interrupted run leaves that), and at the end with the state of the
 * folder. */
static wf_status write_manifest(wf_survey_ctx *ctx, const wf_survey_run_stats *stats, const char *status,
                                const char *note)
{
    const wf_config *cfg = ctx->base;
    const wf_survey_run_options *opt = ctx->opt;
    const wf_survey_row *rows = ctx->rows;
    product *p = ctx->p;
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/survey_run.txt", cfg->out_dir);
    char datasum[FLEN_VALUE] = "";
    fitsfile *f;
    int fst = 0;
    if (!fits_open_diskfile(&f, opt->plan_path, READONLY, &fst)) {
        fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &fst);
        fits_read_key_str(f, "DATASUM", datasum, NULL, &fst);
        int cs = 0;
        fits_close_file(f, &cs);
    }
    fits_clear_errmsg();
    int nscas = opt->nscas ? opt->nscas : WF_NSCA;
    /* the run-wide parts: those of the first item (only the configuration's is per product) */
    wf_status st = prepare(ctx, 0, ctx->cache, p);
    if (st) return st;
    wf_digest run = p->digest;
    char *lines = NULL;
    if ((st = wf_digest_config_lines(cfg, &lines))) return st;
    char(*others)[32] = NULL;
    size_t nothers = 0;
    if ((st = other_products(ctx, &others, &nothers))) {
        free(lines);
        return st;
    }
    static const char *const kinds[] = {"synthetic", "catalog", "grid", "galsim"};
    FILE *out;
    if ((st = wf_file_text_open(path, tmp, sizeof tmp, &out))) {
        free(lines);
        free(others);
        return st;
    }
    fprintf(out, "# wfisim survey run: the inputs of the products in this folder\n");
    fprintf(out, "status = %s\n", status);
    fprintf(out, "wfisim = %s\n", opt->version ? opt->version : "?");
    fprintf(out, "plan = %s\nplan.datasum = %s\n", opt->plan_path, datasum);
    fprintf(out, "exposures = %d:%d\n", rows[0].expid, rows[ctx->nrows - 1].expid);
    fprintf(out, "scas =");
    for (int k = 0; k < nscas; k++) fprintf(out, " %d", opt->nscas ? opt->scas[k] : k + 1);
    fprintf(out, "\nseed = %llu\nmode = %s\nsampling = %s\n", (unsigned long long)cfg->seed,
            cfg->ro.mode == WF_MODE_SINGLE ? "single" : "ramp", cfg->ro.sampling == WF_SAMPLE_DIRECT ? "direct" : "per-read");
    fprintf(out, "scene.kind = %s\n", kinds[cfg->scene_kind]);
    if (cfg->scene_kind == 0)
        fprintf(out, "catalogs = synthetic field of seed %llu (`wfisim catalog --seed %llu` writes it)\n",
                (unsigned long long)cfg->seed, (unsigned long long)cfg->seed);
    else
        fprintf(out, "scene.catalog = %s\nscene.stars = %s\n", cfg->catalog, cfg->stars);
    fprintf(out, "sne = %s\n", opt->sne_path ? opt->sne_path : "(none)");
    fprintf(out, "paths.data = %s\n", cfg->data_dir[0] ? cfg->data_dir : "(none: built-in values)");
    if (opt->area)
        fprintf(out, "area = %.10g,%.10g,%.10g (RA, Dec, radius, deg: the SCAs whose footprint overlaps it)\n",
                opt->area_ra, opt->area_dec, opt->area_radius);
    fprintf(out, "on_change = %s\n", opt->redo_changed ? "redo" : "refuse");
    fprintf(out, "index = survey_index.fits, survey_index.csv\n");
    fprintf(out, "# digests of the inputs (docs/SURVEY.md); the configuration's is per product (WFDCONF:\n"
                 "# the keys below, off their defaults, and the product's plan row)\n");
    for (int q = 0; q < WF_DIGEST_NPARTS; q++)
        if (q != WF_DIGEST_CONFIG) fprintf(out, "digest.%s = %s\n", wf_digest_part_name[q], run.part[q]);
    for (char *l = lines, *nl; *l; l = nl + 1) {
        nl = strchr(l, '\n');
        fprintf(out, "config: %.*s\n", (int)(nl - l), l);
    }
    free(lines);
    fprintf(out, "products.rendered = %ld\nproducts.skipped = %ld\nproducts.redone = %ld\nproducts.changed = %ld\n",
            stats->rendered, stats->skipped, stats->redone, stats->changed);
    if (opt->area) fprintf(out, "products.outside_area = %ld\n", stats->outside);
    if (note) fputs(note, out);
    /* every item of the run as it stands */
    fprintf(out, "# the products of the run: file, WFDIGEST in its header, whether this run's inputs made it\n");
    for (size_t i = 0; i < ctx->nitems && !st; i++) {
        if ((st = prepare(ctx, i, ctx->cache, p))) break;
        const char *name = strrchr(p->image, '/') ? strrchr(p->image, '/') + 1 : p->image;
        wf_digest_found was;
        if (!exists(p->image)) fprintf(out, "product %s missing\n", name);
        else if (wf_digest_read(p->image, &was)) fprintf(out, "product %s unreadable\n", name);
        else {
            fprintf(out, "product %s %s %s\n", name, was.have ? was.d.whole : "(no digest)",
                    wf_digest_same(&was, &p->digest) ? "this run's inputs" : "OTHER INPUTS");
            wf_digest_found_free(&was);
        }
    }
    /* products of the folder that are not items of this run: made by other runs, their
     * headers say by what */
    if (!st && nothers)
        fprintf(out, "# other products of this folder (not items of this run): the parts of their inputs that differ from this run's\n");
    for (size_t j = 0; j < nothers && !st; j++) {
        char full[WF_PATH_MAX + 64];
        snprintf(full, sizeof full, "%s/%s", cfg->out_dir, others[j]);
        wf_digest_found was;
        if (wf_digest_read(full, &was)) { fprintf(out, "other %s unreadable\n", others[j]); continue; }
        fprintf(out, "other %s %s", others[j], was.have ? was.d.whole : "(no digest: inputs unknown)");
        if (was.have) {
            int n = 0;
            for (int q = 0; q < WF_DIGEST_NPARTS; q++)
                if (q != WF_DIGEST_CONFIG && strncmp(was.d.part[q], run.part[q], WF_DIGEST_PART_HEX))
                    fprintf(out, "%s%s", n++ ? ", " : " differs: ", wf_digest_part_name[q]);
            if (!n) fprintf(out, " same seed, data, catalogs, sne and version");
        }
        fprintf(out, "\n");
        wf_digest_found_free(&was);
    }
    free(others);
    fits_clear_errmsg();
    if (st) {
        fclose(out);
        remove(tmp);
        return st;
    }
    return wf_file_text_commit(out, tmp, path);
}

/* Whether an SCA's footprint at this pointing overlaps the circle of --area: the footprint
 * grown by the radius holds the circle's centre (sim/survey/skyindex.h, exact on the sphere). */
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
    wf_status st = wf_survey_read_plan(opt->plan_path, &ctx->plan, &ctx->nplan);
    if (st) { free(ctx); return st; }
    if ((st = select_rows(ctx->plan, ctx->nplan, opt->first, opt->last, &ctx->rows, &ctx->full, &ctx->nrows))) {
        wf_survey_free(ctx);
        return st;
    }
    ctx->scratch = malloc(sizeof *ctx->scratch);
    /* test hook: every history drawn whole (the products must not change) */
    const char *hook = getenv("WFISIM_TEST_PERSIST_CACHE");
    int cache_on = !(hook && !strcmp(hook, "off"));
    /* one: the items of an SCA and filter follow one another (wf_survey_run's walks, the MPI
     * ranks'), and a process holds no more PSFs than before */
    if (!ctx->scratch || (cache_on && wf_persist_cache_new(&ctx->pcache)) || wf_scene_psf_cache_new(1, &ctx->psfs)) {
        wf_survey_free(ctx);
        return wf_error(WF_ERR_NOMEM, "out of memory");
    }
    if (!ctx->nrows) st = wf_error(WF_ERR_INPUT, "%s: no exposure in the range asked for", opt->plan_path);
    int nscas = opt->nscas ? opt->nscas : WF_NSCA;
    size_t most = (ctx->nrows ? ctx->nrows : 1) * (size_t)nscas;
    ctx->p = malloc(sizeof *ctx->p);
    ctx->job = malloc(sizeof *ctx->job);
    ctx->items = malloc(most * sizeof *ctx->items);
    ctx->state = calloc(most, 1);
    ctx->hist = calloc(most, sizeof *ctx->hist);
    if (!st && (!ctx->p || !ctx->job || !ctx->items || !ctx->state || !ctx->hist))
        st = wf_error(WF_ERR_NOMEM, "out of memory");
    if (!st) st = wf_digest_cache_create(&ctx->cache);
    for (size_t i = 0; i < ctx->nrows && !st; i++)
        for (int k = 0; k < nscas && !st; k++) {
            int sca = opt->nscas ? opt->scas[k] : k + 1, inside = 1;
            if (opt->area) {
                wf_clock clock;
                if (!(st = configure(base, opt, &ctx->rows[i], sca, &ctx->p->cfg, &clock)))
                    st = in_area(&ctx->p->cfg, opt, &inside);
            }
            if (!inside) {
                ctx->outside++;
                continue;
            }
            ctx->items[ctx->nitems] = (wf_survey_item){(int)i, sca};
            st = history_rows(base, opt, ctx->plan, ctx->full[i], sca, ctx->scratch, &ctx->hist[ctx->nitems++]);
        }
    if (!st && !ctx->nitems) st = wf_error(WF_ERR_INPUT, "--area: no SCA of the exposures asked for overlaps it");
    if (st) { wf_survey_free(ctx); return st; }
    *out = ctx;
    *nitems = ctx->nitems;
    return WF_OK;
}

wf_status wf_survey_check_inputs(wf_survey_ctx *ctx)
{
    const wf_survey_run_options *opt = ctx->opt;
    product *p = ctx->p;
    long changed = 0;
    char first_change[WF_PATH_MAX + 64 + 1600] = "";
    wf_status st = WF_OK;
    /* A product made from other inputs is refused (the default) or redone, never taken as
     * done; the damage of a product with this run's digest is left to wf_survey_make_item
     * (its checksums are verified where it is made). */
    for (size_t i = 0; i < ctx->nitems && !st; i++) {
        if ((st = prepare(ctx, i, ctx->cache, p))) break;
        unsigned char *s = &ctx->state[i];
        *s = P_MISSING;
        if (!exists(p->image)) continue;
        wf_digest_found was;
        if (wf_digest_read(p->image, &was)) { *s = P_UNREADABLE; continue; } /* damaged: redone */
        *s = wf_digest_same(&was, &p->digest) ? P_SAME : P_CHANGED;
        /* a digest damaged with the rest is damage, redone, not other inputs */
        if (*s == P_CHANGED && !wf_survey_product_ok(p->image)) *s = P_UNREADABLE;
        /* an image with a truth from other inputs (or none) is an incomplete pair: redone */
        wf_digest_found truth;
        if (*s == P_SAME && (!exists(p->truth) || wf_digest_read(p->truth, &truth)))
            *s = P_UNREADABLE;
        else if (*s == P_SAME) {
            if (!wf_digest_same(&truth, &p->digest)) *s = P_UNREADABLE;
            wf_digest_found_free(&truth);
        }
        if (*s == P_CHANGED && !changed++) {
            char why[1536];
            wf_digest_inputs in = {&p->cfg, &p->clock, p->extra, NULL, opt->sne, NULL, 0, opt->version};
            wf_digest_explain(&was, &p->digest, &in, why, sizeof why);
            snprintf(first_change, sizeof first_change, "%s was made with %s", p->image, why);
        }
        wf_digest_found_free(&was);
    }
    fits_clear_errmsg();
    if (!st && changed && !opt->redo_changed) {
        char more[96] = "";
        if (changed > 1) snprintf(more, sizeof more, " (%ld products of the run were made from other inputs)", changed);
        st = wf_error(WF_ERR_INPUT, "%s; use --on-change redo to remake it%s", first_change, more);
    }
    ctx->todo = 0;
    for (size_t i = 0; !st && i < ctx->nitems; i++) ctx->todo += ctx->state[i] != P_SAME;
    if (!st) st = wf_file_make_dir(ctx->base->out_dir);
    wf_survey_run_stats none;
    memset(&none, 0, sizeof none);
    if (!st && ctx->todo) st = write_manifest(ctx, &none, "in progress (an interrupted run leaves this)", NULL);
    if (st) memset(ctx->state, P_UNCHECKED, ctx->nitems); /* refused: nothing is made */
    return st;
}

unsigned char *wf_survey_item_states(wf_survey_ctx *ctx)
{
    return ctx->state;
}

/* PSFs this process has built so far. */
static long psfs_built(const wf_survey_ctx *ctx)
{
    wf_scene_psf_cache_stats s;
    wf_scene_psf_cache_get_stats(ctx->psfs, &s);
    return s.built;
}

wf_status wf_survey_item_before_fork(wf_survey_ctx *ctx, size_t i, int *psf_built)
{
    *psf_built = 0;
    wf_status st = prepare(ctx, i, ctx->cache, ctx->p);
    if (st || ctx->state[i] == P_SAME || ctx->p->cfg.scene_kind == 2) /* skipped, most likely; a grid */
        return st;
    wf_scene_setup ss;
    const wf_config *cfg = &ctx->p->cfg;
    wf_pipeline_scene_setup(cfg, &ctx->p->clock, cfg->threads < 1 ? 1 : cfg->threads, &ss);
    ss.psf_cache = ctx->psfs;
    /* the wide PSF too: nearly every SCA of the deep fields has a star it draws, and it is
     * built once for the items of one SCA and filter; a failure is left to the child */
    const long before = psfs_built(ctx);
    (void)wf_scene_psf_prefetch(&ss, ss.bright_mag >= -50.0);
    *psf_built = (int)(psfs_built(ctx) - before);
    return WF_OK;
}

unsigned long wf_survey_history_mark(const wf_survey_ctx *ctx)
{
    return wf_persist_cache_mark(ctx->pcache);
}

wf_status wf_survey_history_export(const wf_survey_ctx *ctx, unsigned long mark, void **buf, size_t *size)
{
    return wf_persist_cache_export(ctx->pcache, mark, buf, size);
}

wf_status wf_survey_history_import(wf_survey_ctx *ctx, const void *buf, size_t size)
{
    return wf_persist_cache_import(ctx->pcache, buf, size);
}

wf_status wf_survey_walks(const wf_survey_ctx *ctx, size_t nworkers, size_t **order, size_t **start, size_t *nwalks)
{
    size_t n = ctx->nitems, len = nworkers ? (n + 2 * nworkers - 1) / (2 * nworkers) : n, w = 0;
    if (len < 1) len = 1;
    size_t *walk = malloc((n ? n : 1) * sizeof *walk), *cursor = malloc((n + 1) * sizeof *cursor);
    *order = malloc((n ? n : 1) * sizeof **order);
    *start = calloc(n + 1, sizeof **start);
    if (!walk || !cursor || !*order || !*start) {
        free(walk);
        free(cursor);
        free(*order);
        free(*start);
        *order = *start = NULL;
        return wf_error(WF_ERR_NOMEM, "out of memory for the walks");
    }
    /* the items are in plan order: each goes on its SCA's open walk, or opens one (numbered
     * in order of their first item) when that holds len */
    size_t open[WF_NSCA + 1] = {0}, count[WF_NSCA + 1] = {0};
    for (size_t i = 0; i < n; i++) {
        int sca = ctx->items[i].sca;
        if (count[sca]++ % len == 0) open[sca] = w++;
        walk[i] = open[sca];
    }
    for (size_t i = 0; i < n; i++) (*start)[walk[i] + 1]++;
    for (size_t q = 0; q < w; q++) (*start)[q + 1] += (*start)[q];
    memcpy(cursor, *start, (w + 1) * sizeof *cursor);
    for (size_t i = 0; i < n; i++) (*order)[cursor[walk[i]]++] = i; /* plan order within a walk */
    free(walk);
    free(cursor);
    *nwalks = w;
    return WF_OK;
}

void wf_survey_item_name(const wf_survey_ctx *ctx, size_t i, char *buf, size_t cap)
{
    snprintf(buf, cap, "exposure %d SCA %d", ctx->rows[ctx->items[i].row].expid, ctx->items[i].sca);
}

const char *wf_survey_item_note(const wf_survey_item_result *res)
{
    return res->changed ? " (made from other inputs: redone)" : res->redone ? " (damaged product redone)" : "";
}

/* The charge a pixel's history is capped at: the full well, when the detector has one. Both
 * a history and an exposure's own slot (the layer) keep what it says. */
static double history_full_well(const wf_config *cfg)
{
    return cfg->ro.det.on.saturation ? cfg->ro.det.full_well : INFINITY;
}

static wf_status open_planes(wf_survey_ctx *ctx);

typedef struct history_find { wf_survey_ctx *ctx; const wf_clock *clock; } history_find;

/* wf_persist_plane_fn: the scene cache's entry of the earlier exposure ctx->scratch
 * describes, when it holds one with the layer that exposure's own product handed over.
 * Asked only for a slot the process's persistence cache does not hold. */
static wf_status history_plane(void *arg, wf_plane_entry **out)
{
    history_find *f = arg;
    wf_survey_ctx *ctx = f->ctx;
    *out = NULL;
    wf_status st = open_planes(ctx);
    if (st || !ctx->planes || ctx->scratch->scene_kind == 2) return st;
    wf_pipeline_job job;
    memset(&job, 0, sizeof job);
    job.cfg = ctx->scratch;
    job.clock = f->clock;
    job.injector = ctx->opt->sne;
    job.version = ctx->opt->version;
    job.digests = ctx->cache;
    char key[65];
    if ((st = wf_pipeline_plane_key(&job, 1, key))) return st;
    return wf_plane_entry_find(ctx->planes, key, ctx->scratch->ro.ncols, ctx->scratch->ro.nrows, 1, out);
}

/* The item's history, each earlier exposure drawn as its own product would be (tools/persist.h),
 * taken from the process's cache, or read from the scene cache's layer of that exposure's
 * scene; *drawn: how many were drawn. */
static wf_status build_history(wf_survey_ctx *ctx, size_t i, const history *h, const wf_config *cfg,
                               wf_persist_history **out, wf_persist_source *src, int *drawn)
{
    wf_persist_history *ph;
    *drawn = 0;
    wf_status st = wf_persist_history_new(cfg->ro.ncols, cfg->ro.nrows, cfg->persist.min_stimulus,
                                          history_full_well(cfg), &ph);
    for (int j = 0; j < h->n && !st; j++) {
        const wf_survey_row *r = &ctx->plan[h->row[j]];
        wf_clock clock;
        int d = 1;
        history_find f = {ctx, &clock};
        if (!(st = configure(ctx->base, ctx->opt, r, ctx->items[i].sca, ctx->scratch, &clock)))
            st = wf_persist_history_add_exposure(ph, ctx->scratch, &clock, h->dt[j], ctx->pcache, ctx->psfs,
                                                 history_plane, &f, &d);
        if (st) st = wf_error(st, "persistence history from exposure %d: %s", r->expid, wf_error_message());
        *drawn += d;
    }
    if (st) { wf_persist_history_free(ph); return st; }
    wf_persist_history_source(ph, src);
    *out = ph;
    return WF_OK;
}

/* The scene cache of run.scene_cache (auto: in the output folder), opened once; a folder that
 * cannot be made fails every item alike, with the same message. */
static wf_status open_planes(wf_survey_ctx *ctx)
{
    if (ctx->planes_tried) return ctx->planes_st ? wf_error(ctx->planes_st, "%s", ctx->planes_msg) : WF_OK;
    ctx->planes_tried = 1;
    const wf_config *b = ctx->base;
    if (!strcmp(b->scene_cache, "none")) return WF_OK;
    char dir[WF_PATH_MAX + 16];
    if (!strcmp(b->scene_cache, "auto")) snprintf(dir, sizeof dir, "%s/scene_cache", b->out_dir);
    else snprintf(dir, sizeof dir, "%s", b->scene_cache);
    if ((ctx->planes_st = wf_plane_cache_open(dir, b->scene_cache_gib * 1073741824.0, &ctx->planes)))
        snprintf(ctx->planes_msg, sizeof ctx->planes_msg, "run.scene_cache: %s", wf_error_message());
    return ctx->planes_st ? wf_error(ctx->planes_st, "%s", ctx->planes_msg) : WF_OK;
}

wf_status wf_survey_make_item(wf_survey_ctx *ctx, size_t i, wf_survey_item_result *res)
{
    memset(res, 0, sizeof *res);
    int state = ctx->state[i];
    char name[64];
    wf_survey_item_name(ctx, i, name, sizeof name);
    if (state == P_UNCHECKED) return wf_error(WF_ERR_INPUT, "%s: made before the run's check", name);
    product *p = ctx->p;
    const history *h = &ctx->hist[i];
    wf_status st = prepare(ctx, i, NULL, p);
    if (st) return st;
    if (!(state == P_SAME && wf_survey_product_ok(p->image) && wf_survey_product_ok(p->truth))) {
        /* the truth beside an image from other inputs goes first: an interruption then
         * leaves the pair incomplete, redone next time, never a new image with old truth */
        remove(p->truth);
        wf_pipeline_job *job = ctx->job;
        memset(job, 0, sizeof *job);
        job->cfg = &p->cfg;
        job->clock = &p->clock;
        job->meta_extra = p->extra;
        job->injector = ctx->opt->sne;
        job->version = ctx->opt->version;
        job->digests = ctx->cache;
        job->psfs = ctx->psfs;
        if ((st = open_planes(ctx))) return wf_error(st, "%s: %s", name, wf_error_message());
        job->planes = ctx->planes;
        p->cfg.quiet = 1;
        wf_persist_history *ph = NULL;
        wf_persist_source src;
        int drawn = 0;
        const long psfs_before = psfs_built(ctx);
        if (h->n && (st = build_history(ctx, i, h, &p->cfg, &ph, &src, &drawn)))
            return wf_error(st, "%s: %s", name, wf_error_message());
        res->hist_used = h->n;
        res->hist_drawn = drawn;
        if (ph) job->persist = &src;
        /* this exposure's own slot, for the later items of its SCA, taken from its drawing */
        wf_persist_layer *layer = NULL;
        if (ctx->pcache && p->cfg.ro.persist.on && p->cfg.persist.depth > 0 &&
            (st = wf_persist_layer_new(&p->cfg, &p->clock, p->cfg.persist.min_stimulus, history_full_well(&p->cfg),
                                       &layer))) {
            wf_persist_history_free(ph);
            return wf_error(st, "%s: %s", name, wf_error_message());
        }
        job->layer = layer;
        st = wf_pipeline_expose(job);
        if (!st && layer) st = wf_persist_layer_finish(layer, ctx->pcache, p->cfg.ro.exposure, (int)p->cfg.ro.sca);
        wf_persist_layer_free(layer);
        job->layer = NULL;
        res->plane_found = job->plane_found;
        res->plane_not_kept = job->plane_not_kept;
        wf_persist_history_free(ph);
        if (st) {
            char msg[1024];
            snprintf(msg, sizeof msg, "%s", wf_error_message());
            return wf_error(st, "%s: %s", name, msg);
        }
        res->psf_built = (int32_t)(psfs_built(ctx) - psfs_before);
        res->made = 1;
        res->changed = state == P_CHANGED;
        res->redone = state != P_CHANGED && state != P_MISSING;
        res->sne = (int64_t)job->nsne_drawn;
    }
    const char *file = strrchr(p->image, '/');
    st = wf_survey_index_read(p->cfg.out_dir, file ? file + 1 : p->image, &res->row);
    res->done = !st;
    return st;
}

wf_status wf_survey_lost(const wf_survey_ctx *ctx, const unsigned char *lost, const char *prefix)
{
    size_t nlost = 0, named = 0, k = 0;
    for (size_t i = 0; i < ctx->nitems; i++) nlost += lost[i] != 0;
    char buf[2048], name[64];
    k = (size_t)snprintf(buf, sizeof buf, "%s%s%zu of %zu items lost (their process crashed; a rerun makes them): ",
                         prefix, *prefix ? "; " : "", nlost, ctx->nitems);
    for (size_t i = 0; i < ctx->nitems && k < sizeof buf; i++) {
        if (!lost[i]) continue;
        if (named == 20) {
            snprintf(buf + k, sizeof buf - k, ", ... (%zu more)", nlost - named);
            break;
        }
        wf_survey_item_name(ctx, i, name, sizeof name);
        k += (size_t)snprintf(buf + k, sizeof buf - k, "%s%s", named++ ? ", " : "", name);
    }
    return wf_error(WF_ERR_INTERNAL, "%s", buf);
}

static void tally(const wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_survey_run_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    stats->outside = ctx->outside;
    for (size_t i = 0; i < ctx->nitems; i++) {
        if (!res[i].done) continue;
        if (res[i].made) stats->rendered++;
        else stats->skipped++;
        stats->redone += res[i].redone;
        stats->changed += res[i].changed;
        stats->sne_drawn += (long)res[i].sne;
        stats->hist_used += res[i].hist_used;
        stats->hist_drawn += res[i].hist_drawn;
        stats->psf_built += res[i].psf_built;
        stats->planes_found += res[i].plane_found;
        stats->planes_not_kept += res[i].plane_not_kept;
    }
}

wf_status wf_survey_end(wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_survey_run_stats *stats)
{
    tally(ctx, res, stats);
    if (ctx->planes) {
        wf_plane_cache_stats ps;
        wf_plane_cache_get_stats(ctx->planes, &ps);
        snprintf(stats->planes_reason, sizeof stats->planes_reason, "%s", ps.reason);
    }
    wf_survey_index_row *rows = malloc(ctx->nitems * sizeof *rows);
    if (!rows) return wf_error(WF_ERR_NOMEM, "out of memory for the index");
    for (size_t i = 0; i < ctx->nitems; i++) rows[i] = res[i].row;
    const wf_survey_run_options *opt = ctx->opt;
    wf_status st = wf_survey_index_write(ctx->base->out_dir, rows, ctx->nitems);
    char note[1024] = "";
    double centre[2] = {opt->area_ra, opt->area_dec};
    if (!st && opt->sne_path)
        st = wf_survey_write_release(ctx->base, opt->plan_path, opt->sne_path, opt->sne_model, opt->area ? centre : NULL,
                                     rows, ctx->nitems, note, sizeof note);
    free(rows);
    if (!st) st = write_manifest(ctx, stats, "complete", note);
    return st;
}

wf_status wf_survey_end_failed(wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_status st,
                               wf_survey_run_stats *stats)
{
    tally(ctx, res, stats);
    char msg[1100];
    snprintf(msg, sizeof msg, "failed: %s", wf_error_message());
    /* the record says what the folder holds after a failure too (not after a refusal: then
     * nothing was written) */
    if (ctx->todo) write_manifest(ctx, stats, msg, NULL);
    return wf_error(st, "%s", msg + 8);
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
    if (!st) st = wf_survey_check_inputs(ctx);
    if (st) {
        free(res);
        wf_survey_free(ctx);
        return st;
    }
    time_t t0 = time(NULL);
    unsigned char *lost = opt->isolate ? calloc(n, 1) : NULL;
    size_t nlost = 0, *order = NULL, *start = NULL, nwalks;
    if (opt->isolate && !lost) st = wf_error(WF_ERR_NOMEM, "out of memory");
    /* SCA by SCA, each one's exposures in plan order (one walk per SCA): the items of an SCA
     * and filter follow one another and share their PSF (ctx->psfs) */
    if (!st) st = wf_survey_walks(ctx, 0, &order, &start, &nwalks);
    for (size_t k = 0; k < n && !st; k++) {
        size_t i = order[k];
        int crashed = 0;
        st = opt->isolate ? wf_survey_make_item_isolated(ctx, i, &res[i], &crashed) : wf_survey_make_item(ctx, i, &res[i]);
        if (st && crashed) { /* that item alone is lost: the run goes on, and fails at the end */
            fprintf(stderr, "wfisim survey: lost, the other items go on: %s\n", wf_error_message());
            lost[i] = 1;
            nlost++;
            st = WF_OK;
            continue;
        }
        if (st) break;
        if (!base->quiet && res[i].made) {
            const wf_survey_row *x = &ctx->rows[ctx->items[i].row];
            fprintf(stderr, "wfisim survey: [%zu/%zu] exposure %d SCA %d %s MJD %.5f%s (%.0f s)\n", k + 1, n,
                    x->expid, ctx->items[i].sca, x->filter, x->mjd_mid, wf_survey_item_note(&res[i]),
                    difftime(time(NULL), t0));
        }
    }
    if (nlost) {
        char first[1100] = "";
        if (st) snprintf(first, sizeof first, "%s", wf_error_message());
        st = wf_survey_lost(ctx, lost, first);
    }
    st = st ? wf_survey_end_failed(ctx, res, st, stats) : wf_survey_end(ctx, res, stats);
    free(order);
    free(start);
    free(lost);
    free(res);
    wf_survey_free(ctx);
    return st;
}
