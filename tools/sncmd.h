/* `wfisim sn generate | lightcurves | lightcurve`: the supernova sample of a survey, its truth
 * light curves on any time grid, and one light curve on demand (docs/SUPERNOVAE.md). */
#ifndef WF_SNCMD_H
#define WF_SNCMD_H

#include <stddef.h>
#include "hal/status.h"

/* `wfisim sn lightcurves --sne SNE --plan PLAN --out OUT`: the truth light curve of every SN
 * on every image of the plan whose SCA holds it (LIGHTCURVES table); *npoints rows. data may be
 * "" (built-in bandpasses). */
wf_status wf_sn_write_plan_lightcurves(const char *sne, const char *plan, const char *model, const char *data,
                                       const char *out, size_t *npoints);

/* argv[0] is the subcommand; returns the exit code (2 for bad usage or input). */
int wf_cmd_sn(int argc, char **argv);

#endif
