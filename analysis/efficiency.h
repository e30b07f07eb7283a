/* `wfisim efficiency`: detection efficiency against true magnitude (docs/ANALYSIS.md,
 * "wfisim efficiency").
 *
 * Input: a list file, one image a line, `IMAGE DETCAT TRUTH[,TRUTH...]` (`#` comments and
 * blank lines ignored): the image detected (a product, coadd or difference image: SCI with a
 * TAN[-SIP] WCS, ERR and DQ when present), its `wfisim detect` catalog (RA, DEC) and its
 * truth tables (GALAXIES, STARS, SNE with ID, RA, DEC, MAG). Within a line galaxies and stars
 * are deduplicated by ID across the truth files, and a supernova listed by several counts once
 * at the magnitude of its mean flux. Truth objects count where the image sees them: inside
 * SCI and on a pixel that detection uses (not DQ DO_NOT_USE, SCI finite, ERR finite and > 0).
 * Truth objects of the scored types are matched one to one to detections within the radius,
 * closest pairs first; a detection matching none of them is false. Every line is pooled.
 *
 * Output (each through a temporary file, renamed only when all are whole):
 * DIR/NAME_efficiency.csv, DIR/NAME_efficiency.png, DIR/NAME_summary.json and, when
 * supernovae are scored, DIR/NAME_SEARCHEFF_PIPELINE_EFF.DAT (SNANA's detection map, one
 * per filter). */
#ifndef WF_EFFICIENCY_H
#define WF_EFFICIENCY_H

#include "analysis/effstats.h"
#include "hal/status.h"

enum { WF_EFF_GALAXY = 0, WF_EFF_STAR, WF_EFF_SN, WF_EFF_NTYPE };

typedef struct wf_eff_options {
    const char *label;      /* NAME of the output files */
    const char *out_dir;    /* DIR (created when absent, one level) */
    double radius_arcsec;   /* match radius [0.3] */
    double bin;             /* magnitude bin [0.25] */
    int types;              /* bit (1 << WF_EFF_*) per type scored [all three] */
    const char *isolated;   /* a `wfisim sn generate` sample: score only SNe isolated from their
                             * hosts (SPEC §8), the others keep their detections unscored [NULL] */
    double iso_factor;      /* isolated: HOSTOFF > this x HOSTA [1.5] */
    double iso_host_mag;    /* ... and the host (its truth MAG in the image) fainter than this [22] */
    int quiet;
} wf_eff_options;

typedef struct wf_eff_summary {
    long n_images, n_det, n_false;
    long n_true[WF_EFF_NTYPE], n_found[WF_EFF_NTYPE]; /* visible truth objects, and found */
    long n_unseen[WF_EFF_NTYPE];  /* truth objects outside SCI, on masked pixels or without flux */
    long n_not_isolated;          /* SNe seen but not scored: near or on a bright host (isolated) */
    wf_eff_fit fit[WF_EFF_NTYPE]; /* ok = 0: not scored or too few to fit */
} wf_eff_summary;

void wf_eff_defaults(wf_eff_options *o);

/* Parses "galaxy,star,sn" (also the plurals) into *types. */
wf_status wf_eff_parse_types(const char *s, int *types);

/* Reads the list and everything it names, scores, and writes the outputs. Bad input (a list
 * line without three fields or naming a missing file, an empty truth file, a catalog without
 * RA/DEC, an image without a WCS) is WF_ERR_INPUT naming the list line and the file, and
 * nothing is written. */
wf_status wf_eff_run(const char *list_path, const wf_eff_options *o, wf_eff_summary *sum);

/* `wfisim efficiency --label NAME --out DIR [--radius 0.3] [--bin 0.25] [--types ...]
 * [--isolated SNE.fits [--iso-factor 1.5] [--iso-host-mag 22]] LIST`:
 * argv holds what follows "efficiency". Returns 0 done, 1 failure, 2 bad usage or input. */
int wf_cmd_efficiency(int argc, char **argv);

#endif
