/* `wfisim sn generate | lightcurves | lightcurve`: the supernova sample of a survey, its truth
 * light curves on any time grid, and one light curve on demand (docs/SUPERNOVAE.md). */
#ifndef WF_SNCMD_H
#define WF_SNCMD_H

/* argv[0] is the subcommand; returns the exit code (2 for bad usage or input). */
int wf_cmd_sn(int argc, char **argv);

#endif
