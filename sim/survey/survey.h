/* The deep-tier observation plan of SPEC §6 (Wang et al. 2023 §2.3) and its coverage.
 *
 * Every number is a parameter whose default is the paper's value (wf_survey_defaults; the
 * keys of wf_survey_set are listed by wf_survey_write_doc). The plan is a list of exposures:
 * visits every visit_interval days; in each visit the pointings are observed in a snake in
 * the first filter, the snake is run backwards in the next filter, and so on; the telescope
 * orient turns by orient_step every orient_period days. docs/SURVEY.md derives the layout,
 * states the conventions and gives the measured numbers.
 *
 * Pointing layout: columns of pointings along the focal plane's short (v) axis, row_step
 * apart within a column, column_step apart between columns, each column centred on the
 * field (so a column with one pointing fewer sits half a step offset). The layout is placed
 * on the sky as the observatory would slew: each pointing's attitude is the field-centre
 * attitude turned about the focal-plane axes, so all pointings of an orient share one
 * inertial roll and their footprints tile without overlap. The PA stored per exposure is
 * GalSim's observatory PA at that boresight (it differs from the orient's nominal PA at the
 * field centre by the convergence of meridians, up to ~1.5 deg at Dec -53).
 */
#ifndef WF_SURVEY_H
#define WF_SURVEY_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "hal/status.h"
#include "sim/survey/wcs.h"

#define WF_SURVEY_MAX_COLUMNS 16
#define WF_SURVEY_MAX_POINTINGS 256
#define WF_SURVEY_MAX_FILTERS 8
#define WF_SURVEY_FILTER_LEN 8      /* including the terminating NUL */
#define WF_SURVEY_MAX_EXPOSURES 10000000
#define WF_SURVEY_NTHRESH 4

typedef struct wf_survey_params {
    double ra, dec;                 /* field centre, deg [71, -53] */
    double mjd_start;               /* start of the first visit [61420.0] */
    int visits;                     /* [146] */
    double visit_interval;          /* days between visit starts [5] */
    double orient_period;           /* days per orient [30] */
    double orient_step;             /* deg the orient turns each period [30] */
    double pa0;                     /* observatory PA of the first orient at the field centre,
                                     * GalSim convention, deg [0] */
    int ncolumns;                   /* [3] */
    int column_count[WF_SURVEY_MAX_COLUMNS]; /* pointings per column [5, 6, 5] */
    double row_step;                /* arcmin between pointings within a column [24] */
    double column_step;             /* arcmin between columns [49] */
    int nfilters;                   /* [4] */
    char filters[WF_SURVEY_MAX_FILTERS][WF_SURVEY_FILTER_LEN]; /* [Y106 J129 H158 F184] */
    int nexptime;                   /* entries in exptime; must equal nfilters */
    double exptime[WF_SURVEY_MAX_FILTERS]; /* s, per filter [300 300 300 900] */
    double slew_time;               /* s, slew + settle between pointings [50] */
    double filter_change_time;      /* s, between filters at one pointing [50] */
    double coverage_pixel;          /* arcsec, cell of the coverage map [36] */
} wf_survey_params;

typedef struct wf_exposure {
    int id;                         /* 0-based running number */
    int visit;                      /* 0-based */
    int orient;                     /* 0-based: whole orient periods since mjd_start */
    int pointing;                   /* 0-based index along the forward snake */
    int pass;                       /* 0-based filter pass in the visit (even: forward) */
    int filter;                     /* index into params.filters */
    double ra, dec;                 /* boresight, deg */
    double pa;                      /* observatory PA at the boresight (GalSim), deg [0, 360) */
    double orient_pa;               /* the orient's PA at the field centre, deg [0, 360) */
    double mjd_start, mjd_mid;      /* days */
    double exptime;                 /* s */
} wf_exposure;

typedef struct wf_survey_plan {
    wf_survey_params par;
    char fp_source[WF_WCS_SOURCE_MAX]; /* focal plane used: "built-in" or its data directory */
    double fpa_du, fpa_dv;          /* deg: SCA centroid offset from the boresight (u0, v0) */
    int npointings;
    int column[WF_SURVEY_MAX_POINTINGS];     /* column of each pointing (snake order) */
    double du[WF_SURVEY_MAX_POINTINGS];      /* deg: boresight offset along the focal-plane u */
    double dv[WF_SURVEY_MAX_POINTINGS];      /* ... and v axes, from the field centre */
    int norients;
    size_t nexp;
    wf_exposure *exp;               /* nexp records, in time order */
} wf_survey_plan;

typedef struct wf_survey_coverage {
    int nx, ny, nfilters;
    double ra0, dec0;               /* tangent point (the field centre), deg */
    double pixel;                   /* cell size at the tangent point, deg */
    /* Exposure counts the areas are given for: 1, 10, 100 and half the visits (rounded up),
     * the last being what docs/SURVEY.md calls "well covered". */
    int threshold[WF_SURVEY_NTHRESH];
    double area[WF_SURVEY_MAX_FILTERS][WF_SURVEY_NTHRESH]; /* deg^2 with >= threshold */
    int max_count[WF_SURVEY_MAX_FILTERS];
    char filters[WF_SURVEY_MAX_FILTERS][WF_SURVEY_FILTER_LEN];
    int32_t *count;                 /* [filter][y][x]; x grows to the west (RA decreasing) */
} wf_survey_coverage;

typedef struct wf_survey_overlap {
    int orients;                    /* distinct orients (snakes) checked */
    long pairs_checked;             /* SCA pairs from different pointings close enough to test */
    long overlapping;               /* of which share area */
    double max_overlap;             /* arcsec^2, largest shared area */
    double min_gap;                 /* arcsec, smallest distance between such SCAs */
    int worst_orient;               /* orient of min_gap (or of max_overlap when overlapping) */
} wf_survey_overlap;

/* The paper's values (SPEC §6). */
void wf_survey_defaults(wf_survey_params *p);

/* One "key=value" override (keys as in wf_survey_write_doc, e.g. "survey.visits=73",
 * "survey.columns=5,6,5", "survey.exptimes=300,300,300,900"). origin names the source in
 * messages (NULL: "--set"). p is unchanged on error. */
wf_status wf_survey_set(wf_survey_params *p, const char *assignment, const char *origin);

/* 1 when the key (before any '=') is a survey key. */
int wf_survey_is_key(const char *assignment);

/* Cross-key checks (filter and exposure-time counts, plan size); plan_make calls it. */
wf_status wf_survey_check(const wf_survey_params *p);

/* Markdown table of every key, its unit, default and meaning. */
void wf_survey_write_doc(FILE *out);

/* The smallest row and column steps (arcmin) at which copies of this focal plane placed as
 * the layout places them cannot overlap (bounding boxes of the SCAs in the focal-plane frame;
 * a safe bound, the exact one is at most a few arcsec smaller). */
wf_status wf_survey_min_steps(const wf_focal_plane *fp, double *row_min, double *column_min);

/* Generates the plan. out->exp is allocated; release with wf_survey_plan_free. */
wf_status wf_survey_plan_make(const wf_survey_params *p, const wf_focal_plane *fp,
                              wf_survey_plan *out);
void wf_survey_plan_free(wf_survey_plan *plan);

/* Exposures per filter covering each cell of a tangent-plane grid about the field centre,
 * computed from the WCS footprints of all 18 SCAs of every exposure, and the areas covered by
 * at least each threshold. Release with wf_survey_coverage_free. */
wf_status wf_survey_coverage_make(const wf_survey_plan *plan, const wf_focal_plane *fp,
                                  wf_survey_coverage *out);
void wf_survey_coverage_free(wf_survey_coverage *cov);

/* Checks that within each snake (all pointings of one orient) no two SCA footprints of
 * different pointings share area; reports the smallest gap between them. */
wf_status wf_survey_check_overlap(const wf_survey_plan *plan, const wf_focal_plane *fp,
                                  wf_survey_overlap *out);

/* FITS products, written to PATH.tmp and renamed on success (no partial file on error):
 * the plan as binary tables PLAN and POINTINGS with every parameter in the primary header
 * (overlap may be NULL), and the coverage map as one image extension per filter with a TAN
 * WCS and the areas as keywords. */
wf_status wf_survey_write_plan(const wf_survey_plan *plan, const wf_survey_overlap *overlap,
                               const char *path);
wf_status wf_survey_write_coverage(const wf_survey_coverage *cov, const char *path);

/* One exposure of a plan file: the PLAN columns its readers use (ORIENTPA is not read). */
typedef struct wf_survey_row {
    int expid, visit, orient, pointing, pass;
    char filter[16];                /* the FILTER text, cut to 15 characters */
    double ra, dec, pa;             /* boresight and GalSim PA, deg */
    double mjd_start, mjd_mid;      /* days */
    double exptime;                 /* s */
} wf_survey_row;

/* The PLAN table of a plan file written by wf_survey_write_plan, in file order. The file must
 * be whole (wf_fits_verify_checksums: its three HDUs' CHECKSUM and DATASUM verify and nothing
 * follows them), since a damaged plan would place every image wrongly. A file that cannot be
 * opened or is not whole, no PLAN table, a missing column or a non-finite number is
 * WF_ERR_INPUT naming the file (and the section, column or row); a failed read WF_ERR_IO.
 * *rows is allocated, also for an empty table: free() it. */
wf_status wf_survey_read_plan(const char *path, wf_survey_row **rows, size_t *n);

#endif
