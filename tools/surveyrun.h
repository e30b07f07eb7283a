/* `wfisim survey run`: every (exposure, SCA) of a range of a plan, rendered by the same
 * pipeline as `wfisim expose` at the exposure's own pointing, PA, filter and mid-time.
 *
 * Resumable: a product is done only if it was made from the same inputs. Before anything is
 * written, every product of the range is compared with this run: its primary header's WFDIGEST
 * (tools/digest.h: configuration, seed, data files, catalogs, SN sample, program version)
 * against the digest this run would give it. A product from other inputs (or from a wfisim
 * before digests) makes the run refuse, naming what changed, unless redo_changed (then it is
 * remade). A product with this run's digest whose image and truth are whole (every HDU's
 * CHECKSUM and DATASUM verify) and whose truth carries the same WFDIGEST is skipped; anything else (missing, truncated, damaged) is
 * rendered again (products are written through temporary files, so an interrupted run leaves
 * no half file). Each product depends only on the plan row, the SCA, the configuration and the
 * seed (noise is keyed by exposure id and SCA), so it is the same whichever other products
 * were run, and whatever run.threads and readout.tile_rows (left out of the digest).
 *
 * Read pattern: up the ramp, each exposure uses the built-in Rev F table whose duration is
 * nearest its planned time (300 s -> table 6, 900 s -> table 11) unless readout.ma_table was
 * given; single-frame mode uses the planned time exactly.
 *
 * Survey level: DIR/survey_run.txt records the plan (and its DATASUM), the catalogs (files, or
 * the synthetic field's seed: `wfisim catalog --seed N` writes that field), the SN sample, the
 * digests of the inputs and every product of the folder with the WFDIGEST its header holds. */
#ifndef WF_SURVEYRUN_H
#define WF_SURVEYRUN_H

#include "tools/config.h"
#include "tools/sninject.h"

#define WF_NSCA 18

typedef struct wf_survey_run_options {
    const char *plan_path;
    long first, last;          /* EXPID range [first, last]; last < 0: to the end */
    int scas[WF_NSCA];         /* SCAs to render, in this order */
    int nscas;                 /* 0: all 18 */
    int ma_table_given;        /* 1: readout.ma_table (given on the command line) applies to all */
    wf_sn_injector *sne;       /* supernovae to inject, or NULL */
    const char *sne_path;      /* their file, for the run's record */
    const char *version;
    int redo_changed;          /* a product made from other inputs: 1 redo, 0 refuse the run */
} wf_survey_run_options;

typedef struct wf_survey_run_stats {
    long rendered, skipped, redone; /* redone: a damaged product was replaced */
    long changed;                   /* products made from other inputs, remade (--on-change redo) */
    long sne_drawn;                 /* SN entries in the truth of the products rendered */
} wf_survey_run_stats;

/* Parses "a:b", "a:" or "a" (inclusive EXPIDs) into *first, *last. */
wf_status wf_survey_parse_range(const char *text, long *first, long *last);

/* Parses "1,2,5-7" into SCA numbers (1..18, no repeats). */
wf_status wf_survey_parse_scas(const char *text, int *scas, int *n);

/* 1 when the FITS file at path is whole (wf_fits_verify_checksums: every HDU's CHECKSUM and
 * DATASUM verify and the HDUs cover the whole file). */
int wf_survey_product_ok(const char *path);

wf_status wf_survey_run(const wf_config *cfg, const wf_survey_run_options *opt,
                        wf_survey_run_stats *stats);

#endif
