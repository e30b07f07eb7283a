#include "tools/surveycmd.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "sim/survey/survey.h"
#include "sim/survey/wcs.h"
#include "tools/config.h"
#include "analysis/plot.h"
#include "tools/surveyindex.h"

static const char *survey_usage =
    "usage: wfisim survey plan [--config FILE] [--data DIR] [--set survey.KEY=VALUE ...]\n"
    "                          [--quiet] --out plan.fits\n"
    "       wfisim survey keys\n"
    "       wfisim survey index DIR\n"
    "\n"
    "  plan   the deep-tier observation plan (SPEC 6) as FITS tables PLAN and POINTINGS, and\n"
    "         the coverage map per filter next to it (plan.fits -> plan_coverage.fits)\n"
    "  keys   the survey.* keys, their defaults and meaning\n"
    "  index  rebuild DIR/survey_index.{fits,csv} from the headers of every product in DIR\n"
    "         (after job arrays over --exposures ranges, or any runs into one folder)\n"
    "\n"
    "  --data DIR   focal plane from DIR/roman/ (GalSim's files); default paths.data, else the\n"
    "               built-in table\n";

static int fail(wf_status st)
{
    const char *m = wf_error_message();
    fprintf(stderr, "wfisim survey: %s\n", m[0] ? m : wf_status_name(st));
    return st == WF_ERR_INPUT || st == WF_ERR_RANGE ? 2 : 1;
}

static int usage_error(const char *fmt, const char *arg)
{
    fprintf(stderr, "wfisim survey: ");
    fprintf(stderr, fmt, arg);
    fprintf(stderr, "\n\n%s", survey_usage);
    return 2;
}

/* plan.fits -> plan_coverage.fits; any other name gets the suffix appended. */
static int coverage_path(const char *out, char *buf, size_t size)
{
    size_t len = strlen(out);
    int n;
    if (len > 5 && !strcmp(out + len - 5, ".fits"))
        n = snprintf(buf, size, "%.*s_coverage.fits", (int)(len - 5), out);
    else
        n = snprintf(buf, size, "%s_coverage.fits", out);
    return n >= 0 && (size_t)n < size;
}

/* One PNG per filter beside the coverage FITS: exposures per cell, east to the left, north up,
 * uncovered cells white. Written after the FITS products; the names go into *names. */
static wf_status coverage_pngs(const wf_survey_coverage *cov, const char *cov_out, char *names, size_t cap)
{
    size_t len = strlen(cov_out);
    size_t stem = len > 5 && !strcmp(cov_out + len - 5, ".fits") ? len - 5 : len;
    size_t plane = (size_t)cov->nx * cov->ny;
    float *img = malloc(plane * sizeof *img);
    if (!img) return wf_error(WF_ERR_NOMEM, "out of memory for the coverage map");
    double hx = 0.5 * cov->nx * cov->pixel, hy = 0.5 * cov->ny * cov->pixel;
    wf_status st = WF_OK;
    names[0] = '\0';
    for (int f = 0; f < cov->nfilters && !st; f++) {
        char path[WF_PATH_MAX + 64], title[128];
        snprintf(path, sizeof path, "%.*s_%s.png", (int)stem, cov_out, cov->filters[f]);
        for (size_t i = 0; i < plane; i++) img[i] = (float)cov->count[(size_t)f * plane + i];
        snprintf(title, sizeof title, "%s exposures per %.0f\" cell: %.2f deg2 >= %d, %.2f deg2 >= 1",
                 cov->filters[f], cov->pixel * 3600.0, cov->area[f][WF_SURVEY_NTHRESH - 1],
                 cov->threshold[WF_SURVEY_NTHRESH - 1], cov->area[f][0]);
        st = wf_plot_map_png(img, cov->nx, cov->ny, hx, -hx, -hy, hy, 1.0,
                             cov->max_count[f] > 1 ? cov->max_count[f] : 2, title,
                             "east offset from field centre (deg)", "north offset (deg)", "exposures", path);
        size_t used = strlen(names);
        snprintf(names + used, cap - used, "%s%s", used ? ", " : "", path);
    }
    free(img);
    return st;
}

static void report(const wf_survey_plan *plan, const wf_survey_overlap *ov,
                   const wf_survey_coverage *cov, const wf_focal_plane *fp, const char *out,
                   const char *cov_out, const char *pngs)
{
    const wf_survey_params *p = &plan->par;
    const wf_exposure *last = &plan->exp[plan->nexp - 1];
    printf("survey plan: %d visits x %d pointings x %d filters = %zu exposures, %d orients, "
           "MJD %.4f .. %.4f\n", p->visits, plan->npointings, p->nfilters, plan->nexp,
           plan->norients, plan->exp[0].mjd_start, last->mjd_start + last->exptime / 86400.0);
    printf("focal plane: %s\n", fp->source);
    printf("snake overlap check: %d orients, %ld SCA pairs tested, %ld overlapping, smallest gap "
           "between pointings %.2f arcsec\n", ov->orients, ov->pairs_checked, ov->overlapping,
           ov->min_gap);
    for (int f = 0; f < cov->nfilters; f++) {
        printf("coverage %-6s:", cov->filters[f]);
        for (int t = 0; t < WF_SURVEY_NTHRESH; t++)
            printf("  >=%d: %.3f deg2", cov->threshold[t], cov->area[f][t]);
        printf("  (max %d)\n", cov->max_count[f]);
    }
    printf("wrote %s and %s\n", out, cov_out);
    if (pngs[0]) printf("coverage maps: %s\n", pngs);
}

static int cmd_plan(int argc, char **argv)
{
    wf_config *cfg = malloc(sizeof *cfg);
    if (!cfg) return fail(wf_error(WF_ERR_NOMEM, "out of memory"));
    wf_config_defaults(cfg);
    wf_survey_params par;
    wf_survey_defaults(&par);
    const char *out = NULL, *data = NULL;
    int quiet = 0, rc = 0;
    wf_status st;
    /* The configuration file first, wherever it stands, so that flags override it. */
    for (int i = 0; i < argc && !rc; i++)
        if (!strcmp(argv[i], "--config")) {
            if (i + 1 >= argc) rc = usage_error("%s needs a file", "--config");
            else if ((st = wf_config_load(cfg, argv[i + 1]))) rc = fail(st);
        }
    for (int i = 0; i < argc && !rc; i++) {
        const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--quiet")) {
            quiet = 1;
            continue;
        }
        if (strcmp(a, "--config") && strcmp(a, "--data") && strcmp(a, "--out") &&
            strcmp(a, "--set")) {
            rc = usage_error("unknown option '%s'", a);
            break;
        }
        if (!val) {
            rc = usage_error("%s needs a value", a);
            break;
        }
        i++;
        if (!strcmp(a, "--data")) {
            data = val;
            if ((st = wf_config_check_dir("--data", data))) rc = fail(st);
        }
        else if (!strcmp(a, "--out")) out = val;
        else if (!strcmp(a, "--set")) {
            st = wf_config_set(cfg, val, "--set"); /* survey.* keys included */
            if (st) rc = fail(st);
        }
    }
    if (!rc && !out) rc = usage_error("%s is required", "--out FILE");
    par = cfg->survey; /* the configuration file's survey: section and --set survey.* */
    if (!data) data = cfg->data_dir;
    char cov_out[WF_PATH_MAX + 32];
    if (!rc && !coverage_path(out, cov_out, sizeof cov_out))
        rc = usage_error("output name '%s' is too long", out);
    wf_focal_plane *fp = NULL;
    wf_survey_plan plan = {0};
    wf_survey_coverage cov = {0};
    wf_survey_overlap ov = {0};
    char pngs[4 * WF_PATH_MAX + 512] = "";
    if (!rc) {
        /* Parameters first: a bad value is bad input whatever the data directory holds. */
        st = wf_survey_check(&par);
        fp = st ? NULL : malloc(sizeof *fp);
        if (!st) st = fp ? wf_wcs_focal_plane(data, fp) : wf_error(WF_ERR_NOMEM, "out of memory");
        if (!st) st = wf_survey_plan_make(&par, fp, &plan);
        if (!st) st = wf_survey_check_overlap(&plan, fp, &ov);
        if (!st) st = wf_survey_coverage_make(&plan, fp, &cov);
        if (!st) st = wf_survey_write_plan(&plan, &ov, out);
        if (!st) {
            st = wf_survey_write_coverage(&cov, cov_out);
            if (st) unlink(out); /* both products or neither */
        }
        if (!st && (st = coverage_pngs(&cov, cov_out, pngs, sizeof pngs))) {
            unlink(out); /* all products or none */
            unlink(cov_out);
        }
        if (st) rc = fail(st);
    }
    if (!rc) {
        if (ov.overlapping)
            fprintf(stderr, "wfisim survey: warning: %ld SCA pairs of one snake overlap (largest "
                    "%.1f arcsec2, orient %d); a supernova there is seen twice per filter and "
                    "visit\n", ov.overlapping, ov.max_overlap, ov.worst_orient);
        if (!quiet) report(&plan, &ov, &cov, fp, out, cov_out, pngs);
    }
    wf_survey_coverage_free(&cov);
    wf_survey_plan_free(&plan);
    free(fp);
    free(cfg);
    return rc;
}

int wf_cmd_survey(int argc, char **argv)
{
    if (argc < 1) return usage_error("%s", "which survey command?");
    if (!strcmp(argv[0], "--help") || !strcmp(argv[0], "-h") || !strcmp(argv[0], "help")) {
        fputs(survey_usage, stdout);
        return 0;
    }
    if (!strcmp(argv[0], "keys")) {
        wf_survey_write_doc(stdout);
        return 0;
    }
    if (!strcmp(argv[0], "plan")) return cmd_plan(argc - 1, argv + 1);
    if (!strcmp(argv[0], "index")) {
        if (argc != 2 || argv[1][0] == '-') return usage_error("%s", "survey index takes one folder: survey index DIR");
        wf_survey_index_row *rows;
        size_t n;
        wf_status st = wf_survey_index_scan(argv[1], &rows, &n);
        if (!st && !n) st = wf_error(WF_ERR_INPUT, "%s: no product (wfisim_eNNNNNN_scaNN.fits) to index", argv[1]);
        if (!st) st = wf_survey_index_write(argv[1], rows, n);
        free(rows);
        if (st) return fail(st);
        printf("wfisim survey: %zu products indexed in %s/survey_index.fits and survey_index.csv\n", n, argv[1]);
        return 0;
    }
    return usage_error("unknown survey command '%s'", argv[0]);
}
