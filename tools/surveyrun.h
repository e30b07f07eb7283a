/* `wfisim survey run`: every (exposure, SCA) of a range of a plan, rendered by the same
 * pipeline as `wfisim expose` at the exposure's own pointing, PA, filter and mid-time.
 *
 * A run is a list of items, (exposure, SCA) pairs in plan order (the range, the SCAs, and with
 * --area only those whose SCA footprint overlaps the circle), in three steps:
 *   check  one process compares every item's product with this run, before anything is
 *          written: its primary header's WFDIGEST (tools/digest.h: configuration, seed, data
 *          files, catalogs, SN sample, program version) against the digest this run would
 *          give it. A product from other inputs (or from a wfisim before digests) makes the
 *          run refuse, naming what changed, unless redo_changed (then it is remade).
 *   make   each item alone (wf_survey_make_item): a product with this run's digest whose
 *          image and truth are whole (every HDU's CHECKSUM and DATASUM verify) and whose
 *          truth carries the same WFDIGEST is skipped; anything else (missing, truncated,
 *          damaged, from other inputs) is rendered again, through temporary files, so an
 *          interrupted run leaves no half file. wf_survey_run makes the items one after
 *          another, SCA by SCA (wf_survey_walks, one walk per SCA), so that the items of an SCA
 *          and filter share one PSF (sim/draw/scene_psf.h); the MPI program
 *          (tools/survey_mpi.c) hands them out to its ranks by the same walks.
 *   end    one process writes the index and survey_run.txt (and the release with an SN
 *          sample) from every item's result.
 * Each product depends only on the plan row, the SCA, the configuration and the seed (noise is
 * keyed by exposure id and SCA), so it is the same whichever other products were run, on
 * however many processes, and whatever run.threads and readout.tile_rows (left out of the
 * digest).
 *
 * Read pattern: up the ramp, each exposure uses the built-in Rev F table whose duration is
 * nearest its planned time (300 s -> table 6, 900 s -> table 11) unless readout.ma_table was
 * given; single-frame mode uses the planned time exactly.
 *
 * Survey level: DIR/survey_run.txt records the plan (and its DATASUM), the catalogs (files, or
 * the synthetic field's seed: `wfisim catalog --seed N` writes that field), the SN sample, the
 * digests of the inputs and every product of the folder with the WFDIGEST its header holds;
 * "status = in progress" from the check until the end. DIR/survey_index.{fits,csv} lists the
 * run's products (tools/surveyindex.h). */
#ifndef WF_SURVEYRUN_H
#define WF_SURVEYRUN_H

#include "tools/config.h"
#include "tools/sninject.h"
#include "tools/surveyindex.h"

#define WF_NSCA 18

typedef struct wf_survey_run_options {
    const char *plan_path;
    long first, last;          /* EXPID range [first, last]; last < 0: to the end */
    int scas[WF_NSCA];         /* SCAs to render, in this order */
    int nscas;                 /* 0: all 18 */
    int ma_table_given;        /* 1: readout.ma_table (given on the command line) applies to all */
    wf_sn_injector *sne;       /* supernovae to inject, or NULL */
    const char *sne_path;      /* their file, for the run's record and the release */
    const char *sne_model;     /* the SALT model they were made with (for the light curves) */
    const char *version;
    int area;                  /* 1: only the items whose SCA footprint overlaps the circle */
    double area_ra, area_dec, area_radius; /* deg */
    int redo_changed;          /* a product made from other inputs: 1 redo, 0 refuse the run */
    int isolate;               /* 1: each item in a child process (tools/isolate.h); a crash
                                * loses that item alone (the MPI program always isolates) */
} wf_survey_run_options;

typedef struct wf_survey_run_stats {
    long rendered, skipped, redone; /* redone: a damaged product was replaced */
    long changed;                   /* products made from other inputs, remade (--on-change redo) */
    long sne_drawn;                 /* SN entries in the truth of the products rendered */
    long outside;                   /* items outside --area, not made */
    long hist_used, hist_drawn;     /* earlier exposures in the persistence histories, and drawn */
    long psf_built;                 /* PSFs built, for the items and their histories' scenes (the
                                     * other items took theirs from the process's cache) */
    long planes_found;              /* products whose static scene came from the scene cache */
    long planes_not_kept;           /* products whose drawn scene the cache could not keep */
    char planes_reason[512];        /* the first reason this process saw ("" when none, or when
                                     * only child processes or other ranks saw one) */
    int silent;                     /* 1: another process reports this run (MPI ranks > 0) */
} wf_survey_run_stats;

/* Parses "a:b", "a:" or "a" (inclusive EXPIDs) into *first, *last. */
wf_status wf_survey_parse_range(const char *text, long *first, long *last);

/* Parses "1,2,5-7" into SCA numbers (1..18, no repeats). */
wf_status wf_survey_parse_scas(const char *text, int *scas, int *n);

/* 1 when the FITS file at path is whole (wf_fits_verify_checksums: every HDU's CHECKSUM and
 * DATASUM verify and the HDUs cover the whole file). */
int wf_survey_product_ok(const char *path);

/* Parses "RA,DEC,RADIUS" (degrees) into opt's area. */
wf_status wf_survey_parse_area(const char *text, wf_survey_run_options *opt);

wf_status wf_survey_run(const wf_config *cfg, const wf_survey_run_options *opt,
                        wf_survey_run_stats *stats);

/* The pieces of a run, for drivers other than wf_survey_run. */
typedef struct wf_survey_ctx wf_survey_ctx;

/* What making one item gave; fixed size and pointer-free, so that it travels as bytes
 * between processes of one build. */
typedef struct wf_survey_item_result {
    int32_t done;          /* 1: the item was made (or found whole) */
    int32_t made;          /* 0 already whole (skipped), 1 rendered */
    int32_t redone;        /* 1: a damaged product was replaced */
    int32_t changed;       /* 1: a product from other inputs was replaced */
    int64_t sne;           /* SNe drawn */
    int32_t hist_used;     /* earlier exposures in its persistence history */
    int32_t hist_drawn;    /* of them drawn for it (the others were in the process's cache) */
    int32_t psf_built;     /* PSFs built for it (by its process, or by the parent before the
                            * fork); 0: it found its PSF kept from an earlier item */
    int32_t plane_found;   /* 1: its static scene came from the scene cache (run.scene_cache) */
    int32_t plane_not_kept; /* 1: its scene was drawn, and the cache could not keep it */
    wf_survey_index_row row;
} wf_survey_item_result;

/* Reads the plan and selects the items (range, SCAs, area); writes nothing. */
wf_status wf_survey_begin(const wf_config *cfg, const wf_survey_run_options *opt, wf_survey_ctx **out,
                          size_t *nitems);
/* In one process, before any item is made: every item's product against this run's inputs.
 * Refuses the run (WF_ERR_INPUT, naming the first product in plan order and what changed)
 * when a product was made from other inputs and opt->redo_changed is 0; else makes the
 * output folder and, when there is work, writes survey_run.txt "in progress". */
wf_status wf_survey_check_inputs(wf_survey_ctx *ctx);
/* The check's verdict, one byte per item: what another process's context needs (copied into
 * it) before it makes items. */
unsigned char *wf_survey_item_states(wf_survey_ctx *ctx);
/* Item i (0-based, plan order), after the check: skipped when its products are whole and
 * from this run's inputs, else rendered. */
wf_status wf_survey_make_item(wf_survey_ctx *ctx, size_t i, wf_survey_item_result *res);
/* What a child process that makes item i needs, made in this process so that it stays for
 * the next items (a child's own is lost with it): the item's input digest (its files' digests
 * stay in the run's cache) and, unless the item will most likely be skipped, its PSF and wide
 * PSF (the next items of its SCA and filter take the same). A PSF that fails to build here is
 * left to the child, which reports it as the item's failure. *psf_built: PSFs built (0, 1). */
wf_status wf_survey_item_before_fork(wf_survey_ctx *ctx, size_t i, int *psf_built);
/* The persistence histories this process's cache took in since mark (wf_survey_history_mark),
 * as bytes for another process's wf_survey_history_import (*buf malloc'd, NULL when none):
 * how an item's child gives what it drew back to the process that makes the next items. */
unsigned long wf_survey_history_mark(const wf_survey_ctx *ctx);
wf_status wf_survey_history_export(const wf_survey_ctx *ctx, unsigned long mark, void **buf, size_t *size);
wf_status wf_survey_history_import(wf_survey_ctx *ctx, const void *buf, size_t size);
/* The items as walks for a run on nworkers processes: a walk is consecutive items of one SCA
 * in plan (exposure) order, so that the process that makes it finds in its cache all the
 * earlier exposures of each history but the newest (tools/persist.h); walks are cut to
 * ceil(items / (2 nworkers)) items, so that every worker has some (nworkers 0: not cut, one
 * walk per SCA), and listed by their first item. (*order)[k] for k in
 * [(*start)[w], (*start)[w + 1]) are walk w's items; both malloc'd. */
wf_status wf_survey_walks(const wf_survey_ctx *ctx, size_t nworkers, size_t **order, size_t **start, size_t *nwalks);
/* "exposure E SCA S" of item i, for messages. */
void wf_survey_item_name(const wf_survey_ctx *ctx, size_t i, char *buf, size_t cap);
/* How item i's result reads in a progress line: "", " (damaged product redone)", ... */
const char *wf_survey_item_note(const wf_survey_item_result *res);
/* The run's error after lost[i] items (1: their process crashed) were lost, the others
 * made: "N of M items lost (...): exposure E SCA S, ...", with prefix (a failure of another
 * kind, or "") before it. */
wf_status wf_survey_lost(const wf_survey_ctx *ctx, const unsigned char *lost, const char *prefix);
/* With every item's result: the stats, the index and survey_run.txt "complete" (and, with an
 * SN sample, the release's catalogs and light curves), each through a temporary file and a
 * rename. */
wf_status wf_survey_end(wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_survey_run_stats *stats);
/* After item failure st (its message current): survey_run.txt "failed: ..." with the folder
 * as it stands and the results known (res[i].done); returns st, its message kept. */
wf_status wf_survey_end_failed(wf_survey_ctx *ctx, const wf_survey_item_result *res, wf_status st,
                               wf_survey_run_stats *stats);
void wf_survey_free(wf_survey_ctx *ctx);

#endif
