/* `wfisim survey run` on many processes (bin/wfisim-mpi, built with `make MPI=1`; the plain
 * program needs no MPI). Every rank reads the plan and selects the same items; rank 0 hands
 * them out one at a time to whichever rank asks next (items differ in cost), by walks
 * (wf_survey_walks: consecutive items of one SCA in exposure order): a rank asking gets the
 * next item of its walk, or starts the next walk, so its cache holds the earlier exposures of
 * each history but the newest. It collects what each made. Each item is made by wf_survey_make_item, exactly as a
 * one-process run makes it, so the products are the same bytes whatever the number of ranks.
 * Before any item is handed out, rank 0 alone checks every item's product against this run's
 * inputs (wf_survey_check_inputs: a refusal names the product one process would name, and nothing
 * is written) and sends its verdict to every rank (which waits for it asleep).
 *
 * Rank 0 dispatches from its main thread (the only one that calls MPI: MPI_THREAD_FUNNELED)
 * and makes items on a second thread, so N ranks are N workers; it polls for requests every
 * millisecond and sleeps in between, so dispatching costs no core. Waiting ranks sleep too
 * (a non-blocking barrier polled with sleeps) instead of spinning in MPI_Finalize.
 *
 * Every rank makes each item in a forked child (tools/isolate.h): an item whose child dies (a
 * signal: SIGSEGV, the OOM killer's SIGKILL, abort) is reported to rank 0, which counts it
 * lost and hands out the rest; the run then fails listing the lost items. A failed item (an
 * error the program reports) stops the handing out; the items in flight finish, and the run
 * fails naming the rank and the item. A rank that dies itself takes the job down (mpirun's
 * default) and loses only the items in flight. Products are renamed into place when whole,
 * so a rerun redoes exactly the missing ones. survey_run.txt is written by rank 0 alone ("in progress"
 * after the check, then with the index and release at the end, or "failed"). */
#ifndef WF_SURVEY_MPI_H
#define WF_SURVEY_MPI_H

#include "tools/surveyrun.h"

/* Calls MPI_Init_thread and MPI_Finalize itself. stats->silent is 1 on ranks > 0 unless the
 * failure returned is the rank's own (then it prints it too). */
wf_status wf_survey_run_mpi(const wf_config *cfg, const wf_survey_run_options *opt,
                            wf_survey_run_stats *stats);

#endif
