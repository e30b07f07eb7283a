#include "tools/surveyrun.h"

#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <dirent.h>
#include <sys/stat.h>

#include "hal/clock.h"
#include "sim/fitsout.h"
#include "sim/survey.h"
#include "tools/digest.h"
#include "tools/pipeline.h"

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
    if (!opt->ma_table_given) {
        char name[8];
        if ((st = nearest_table(cfg->frame_time, x->exptime, name, sizeof name))) return st;
        snprintf(cfg->ma_table, sizeof cfg->ma_table, "%s", name);
    }
    return wf_config_finish(cfg, clock);
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

/* One product of the range: its configuration, header lines, names and input digest. */
typedef struct product {
    wf_config *cfg;
    wf_clock clock;
    char extra[1024];
    char image[WF_PATH_MAX + 64], truth[WF_PATH_MAX + 64];
    wf_digest digest;
} product;

static wf_status prepare(const wf_config *base, const wf_survey_run_options *opt, const wf_survey_row *x, int sca,
                         wf_digest_cache *cache, product *p)
{
    wf_status st = configure(base, opt, x, sca, p->cfg, &p->clock);
    if (st) return st;
    plan_extra(x, p->extra, sizeof p->extra);
    wf_pipeline_paths(p->cfg->out_dir, p->cfg->ro.exposure, p->cfg->ro.sca, p->image, p->truth, sizeof p->image);
    wf_digest_inputs in = {p->cfg, &p->clock, p->extra, NULL, opt->sne, NULL, 0, opt->version};
    return wf_digest_product(cache, &in, &p->digest);
}

static int exists(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0;
}

/* Where a product of the range stands before the run. */
enum { P_MISSING, P_SAME, P_CHANGED, P_UNREADABLE };

/* The survey-level record of a run, DIR/survey_run.txt: the plan (and its checksum), the
 * catalogs the scenes were drawn from, the SN sample, the digests of the inputs, and every
 * product of the folder as it stands (its WFDIGEST, read back from its header), so that the
 * record never claims inputs that did not make a product. Written through a temporary file
 * and a rename: with status "in progress" before the first product is rendered (an
 * interrupted run leaves that), and at the end with the state of the folder. */
static wf_status write_manifest(const wf_config *cfg, const wf_survey_run_options *opt, const wf_survey_row *rows,
                                size_t nrows, const wf_survey_run_stats *stats, const char *status,
                                product *p, wf_digest_cache *cache)
{
    char path[WF_PATH_MAX + 64], tmp[WF_PATH_MAX + 80];
    snprintf(path, sizeof path, "%s/survey_run.txt", cfg->out_dir);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
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
    int all[WF_NSCA];
    for (int s = 0; s < WF_NSCA; s++) all[s] = s + 1;
    const int *scas = opt->nscas ? opt->scas : all;
    int nscas = opt->nscas ? opt->nscas : WF_NSCA;
    /* the run-wide parts: those of the first product (only the configuration's is per product) */
    wf_status st = prepare(cfg, opt, &rows[0], scas[0], cache, p);
    if (st) return st;
    wf_digest run = p->digest;
    char *lines = NULL;
    if ((st = wf_digest_config_lines(cfg, &lines))) return st;
    static const char *const kinds[] = {"synthetic", "catalog", "grid", "galsim"};
    FILE *out = fopen(tmp, "w");
    if (!out) {
        free(lines);
        return wf_error(WF_ERR_IO, "%s: cannot create", tmp);
    }
    fprintf(out, "# wfisim survey run: the inputs of the products in this folder\n");
    fprintf(out, "status = %s\n", status);
    fprintf(out, "wfisim = %s\n", opt->version ? opt->version : "?");
    fprintf(out, "plan = %s\nplan.datasum = %s\n", opt->plan_path, datasum);
    fprintf(out, "exposures = %d:%d\n", rows[0].expid, rows[nrows - 1].expid);
    fprintf(out, "scas =");
    for (int k = 0; k < nscas; k++) fprintf(out, " %d", scas[k]);
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
    fprintf(out, "on_change = %s\n", opt->redo_changed ? "redo" : "refuse");
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
    /* every product of the range as it stands */
    fprintf(out, "# the products of the range: file, WFDIGEST in its header, whether this run's inputs made it\n");
    for (size_t i = 0; i < nrows && !st; i++)
        for (int k = 0; k < nscas && !st; k++) {
            if ((st = prepare(cfg, opt, &rows[i], scas[k], cache, p))) break;
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
    /* products of the folder outside the range: made by other runs, their headers say by what */
    DIR *dir = st ? NULL : opendir(cfg->out_dir);
    int header = 0;
    for (struct dirent *e; dir && (e = readdir(dir));) {
        unsigned expid, sca;
        int used = 0;
        if (sscanf(e->d_name, "wfisim_e%6u_sca%2u.fits%n", &expid, &sca, &used) != 2 || e->d_name[used]) continue;
        int inside = 0;
        for (size_t i = 0; i < nrows && !inside; i++)
            for (int k = 0; k < nscas && !inside; k++) inside = (unsigned)rows[i].expid == expid && (unsigned)scas[k] == sca;
        if (inside) continue;
        if (!header++) fprintf(out, "# other products of this folder (not of this range): the parts of their inputs that differ from this run's\n");
        char full[2 * WF_PATH_MAX];
        snprintf(full, sizeof full, "%s/%s", cfg->out_dir, e->d_name);
        wf_digest_found was;
        if (wf_digest_read(full, &was)) { fprintf(out, "other %s unreadable\n", e->d_name); continue; }
        fprintf(out, "other %s %s", e->d_name, was.have ? was.d.whole : "(no digest: inputs unknown)");
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
    if (dir) closedir(dir);
    int bad = ferror(out);
    if (fclose(out) != 0 || bad) {
        remove(tmp);
        return st ? st : wf_error(WF_ERR_IO, "%s: write failed", tmp);
    }
    if (st || rename(tmp, path) != 0) {
        remove(tmp);
        return st ? st : wf_error(WF_ERR_IO, "%s: cannot rename into place", path);
    }
    return WF_OK;
}

wf_status wf_survey_run(const wf_config *base, const wf_survey_run_options *opt, wf_survey_run_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    wf_survey_row *rows;
    size_t nrows;
    wf_status st = read_plan(opt->plan_path, opt->first, opt->last, &rows, &nrows);
    if (st) return st;
    if (!nrows) {
        free(rows);
        return wf_error(WF_ERR_INPUT, "%s: no exposure in the range asked for", opt->plan_path);
    }
    int all[WF_NSCA];
    for (int s = 0; s < WF_NSCA; s++) all[s] = s + 1;
    const int *scas = opt->nscas ? opt->scas : all;
    int nscas = opt->nscas ? opt->nscas : WF_NSCA;
    size_t total = nrows * (size_t)nscas, done = 0;
    product *p = malloc(sizeof *p);
    wf_config *cfg = malloc(sizeof *cfg);
    wf_pipeline_job *job = malloc(sizeof *job);
    unsigned char *state = malloc(total);
    wf_digest_cache *cache = NULL;
    if (!p || !cfg || !job || !state) st = wf_error(WF_ERR_NOMEM, "out of memory");
    if (!st) st = wf_digest_cache_create(&cache);
    if (p) p->cfg = cfg;
    /* First every product of the range against the inputs of this run, before anything is
     * written: a product made from other inputs is refused (the default) or redone, never
     * taken as done. */
    long changed = 0;
    char first_change[WF_PATH_MAX + 64 + 1600] = "";
    for (size_t i = 0, at = 0; i < nrows && !st; i++)
        for (int k = 0; k < nscas && !st; k++, at++) {
            if ((st = prepare(base, opt, &rows[i], scas[k], cache, p))) break;
            state[at] = P_MISSING;
            if (!exists(p->image)) continue;
            wf_digest_found was;
            if (wf_digest_read(p->image, &was)) { state[at] = P_UNREADABLE; continue; } /* damaged: redone */
            state[at] = wf_digest_same(&was, &p->digest) ? P_SAME : P_CHANGED;
            /* a digest damaged with the rest is damage, redone, not other inputs */
            if (state[at] == P_CHANGED && !wf_survey_product_ok(p->image)) state[at] = P_UNREADABLE;
            /* an image with a truth from other inputs (or none) is an incomplete pair: redone */
            wf_digest_found truth;
            if (state[at] == P_SAME && (!exists(p->truth) || wf_digest_read(p->truth, &truth)))
                state[at] = P_UNREADABLE;
            else if (state[at] == P_SAME) {
                if (!wf_digest_same(&truth, &p->digest)) state[at] = P_UNREADABLE;
                wf_digest_found_free(&truth);
            }
            if (state[at] == P_CHANGED && !changed++) {
                char why[1536];
                wf_digest_inputs in = {p->cfg, &p->clock, p->extra, NULL, opt->sne, NULL, 0, opt->version};
                wf_digest_explain(&was, &p->digest, &in, why, sizeof why);
                snprintf(first_change, sizeof first_change, "%s was made with %s", p->image, why);
            }
            wf_digest_found_free(&was);
        }
    if (!st && changed && !opt->redo_changed) {
        char more[96] = "";
        if (changed > 1) snprintf(more, sizeof more, " (%ld products of the range were made from other inputs)", changed);
        st = wf_error(WF_ERR_INPUT, "%s; use --on-change redo to remake it%s", first_change, more);
    }
    size_t todo = 0;
    for (size_t at = 0; !st && at < total; at++) todo += state[at] != P_SAME;
    if (!st) st = wf_pipeline_make_dir(base->out_dir);
    if (!st && todo) st = write_manifest(base, opt, rows, nrows, stats, "in progress (an interrupted run leaves this)", p, cache);
    time_t t0 = time(NULL);
    for (size_t i = 0, at = 0; i < nrows && !st; i++) {
        for (int k = 0; k < nscas && !st; k++, done++, at++) {
            if ((st = prepare(base, opt, &rows[i], scas[k], cache, p))) break;
            if (state[at] == P_SAME && wf_survey_product_ok(p->image) && wf_survey_product_ok(p->truth)) {
                stats->skipped++;
                continue;
            }
            /* the truth beside an image from other inputs goes first: an interruption then
             * leaves the pair incomplete, redone next time, never a new image with old truth */
            remove(p->truth);
            memset(job, 0, sizeof *job);
            job->cfg = p->cfg;
            job->clock = &p->clock;
            job->meta_extra = p->extra;
            job->injector = opt->sne;
            job->version = opt->version;
            job->digests = cache;
            p->cfg->quiet = 1;
            st = wf_pipeline_expose(job);
            if (st) {
                char msg[1024];
                snprintf(msg, sizeof msg, "%s", wf_error_message());
                st = wf_error(st, "exposure %d SCA %d: %s", rows[i].expid, scas[k], msg);
                break;
            }
            stats->rendered++;
            if (state[at] == P_CHANGED) stats->changed++;
            else if (state[at] != P_MISSING) stats->redone++;
            stats->sne_drawn += (long)job->nsne_drawn;
            if (!base->quiet)
                fprintf(stderr, "wfisim survey: [%zu/%zu] exposure %d SCA %d %s MJD %.5f%s (%.0f s)\n", done + 1,
                        total, rows[i].expid, scas[k], rows[i].filter, rows[i].mjd_mid,
                        state[at] == P_CHANGED ? " (made from other inputs: redone)"
                        : state[at] != P_MISSING ? " (damaged product redone)" : "", difftime(time(NULL), t0));
        }
    }
    /* the record says what the folder holds, after a failure too (not after a refusal:
     * then nothing was written) */
    if (!st) st = write_manifest(base, opt, rows, nrows, stats, "complete", p, cache);
    else if (todo && state && p) {
        char msg[1024];
        snprintf(msg, sizeof msg, "failed: %s", wf_error_message());
        wf_status kept = st;
        write_manifest(base, opt, rows, nrows, stats, msg, p, cache);
        st = wf_error(kept, "%s", msg + 8);
    }
    wf_digest_cache_free(cache);
    free(state);
    free(job);
    free(cfg);
    free(p);
    free(rows);
    return st;
}
