/* `wfisim survey ...`: the survey plan on the command line.
 *
 *   wfisim survey plan [--config FILE] [--data DIR] [--set survey.KEY=VALUE ...] [--quiet]
 *                      --out plan.fits
 *   wfisim survey keys          (the survey.* keys, their defaults and meaning, as Markdown)
 *   wfisim survey index DIR     (DIR/survey_index.{fits,csv} from the products' headers)
 *
 * `plan` writes the plan (tables PLAN and POINTINGS) to the --out file and the coverage map
 * next to it (plan.fits -> plan_coverage.fits), both through a temporary file, and prints
 * the numbers (exposures, areas covered, overlap check). The focal plane comes from
 * DIR/roman/ (--data, else paths.data of the configuration, else $WFISIM_DATA) or, when
 * none is set, from the built-in table. survey.* keys are set with --set until the
 * configuration file learns them; other --set keys go to the configuration.
 */
#ifndef WF_SURVEYCMD_H
#define WF_SURVEYCMD_H

/* argv[0] is the word after "survey" ("plan", "keys"). Returns the process exit status:
 * 0 done, 1 failure (I/O, memory), 2 bad usage or input. */
int wf_cmd_survey(int argc, char **argv);

#endif
