/* The survey-level files of a release, written by `wfisim survey run --sne SNE` beside the
 * per-SCA products and the index (the layout of Wang et al. 2023's data release; docs/SURVEY.md):
 *
 *   input_galaxies.fits, input_stars.fits   the catalogs the scenes were drawn from, every
 *       object within a circle that holds every SCA of the run (and the stamps reaching it)
 *   sne.fits                                the SN sample that was injected (the SNE table as given)
 *   sn_lightcurves.fits                     its truth light curves on every image of the plan
 *                                           whose SCA holds the SN (`wfisim sn lightcurves`)
 *
 * Each through a temporary file and a rename. */
#ifndef WF_SURVEYRELEASE_H
#define WF_SURVEYRELEASE_H

#include "tools/config.h"
#include "tools/surveyindex.h"

/* rows: the run's products (their SCA centres fix the catalogs' circle; area: the --area
 * centre, else NULL). note receives a line for the run's record. */
wf_status wf_survey_write_release(const wf_config *cfg, const char *plan, const char *sne, const char *sne_model,
                                  const double *area, const wf_survey_index_row *rows, size_t n, char *note,
                                  size_t cap);

#endif
