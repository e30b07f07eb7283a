#include "tools/survey_mpi.h"

#include "tools/isolate.h"

#include <mpi.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

enum { TAG_REPORT = 1, TAG_WORK = 2 };

/* Worker -> rank 0: "ready", with the result of the item just made (if any). The ranks are
 * one build of one program, so the struct travels as bytes. */
typedef struct report {
    int32_t status;      /* wf_status of the item */
    int32_t has_result;
    int32_t crashed;     /* the item's process died (wf_isolate_run): the item alone is lost */
    int64_t item;
    wf_survey_item_result res;
    char message[1024];
} report;

static void nap(void)
{
    struct timespec ts = {0, 1000000}; /* 1 ms */
    nanosleep(&ts, NULL);
}

/* What rank 0's dispatcher and its own worker thread share. */
typedef struct shared {
    pthread_mutex_t mu;
    wf_survey_ctx *ctx;
    size_t n, done_items;
    size_t *order, *start, nwalks, next_walk; /* the items as walks (wf_survey_walks) */
    size_t *cur, *end;    /* per rank, the rest of its walk: order[cur .. end) */
    int stop;             /* an item failed: hand out no more */
    unsigned char *lost;  /* per item, 1: its process crashed; the others go on */
    size_t nlost;
    int local_done;
    wf_status st;         /* the first failure */
    char message[1200];
    wf_survey_item_result *res;
    int quiet;
    time_t t0;
} shared;

/* The next item for rank w to make: the next of its walk, or the first of the next walk; -1
 * when none is left or the run is stopping. */
static long long take(shared *s, int w)
{
    pthread_mutex_lock(&s->mu);
    long long i = -1;
    if (!s->stop && s->cur[w] == s->end[w] && s->next_walk < s->nwalks) {
        s->cur[w] = s->start[s->next_walk];
        s->end[w] = s->start[++s->next_walk];
    }
    if (!s->stop && s->cur[w] < s->end[w]) i = (long long)s->order[s->cur[w]++];
    pthread_mutex_unlock(&s->mu);
    return i;
}

static void record(shared *s, int rank, size_t i, wf_status st, int crashed, const char *msg,
                   const wf_survey_item_result *res)
{
    pthread_mutex_lock(&s->mu);
    if (st && crashed) {
        s->lost[i] = 1;
        s->nlost++;
        fprintf(stderr, "wfisim survey: lost on rank %d, the other items go on: %s\n", rank, msg);
    } else if (st) {
        if (!s->st) {
            s->st = st;
            snprintf(s->message, sizeof s->message, "rank %d: %s", rank, msg);
        }
        s->stop = 1;
    } else {
        s->res[i] = *res;
        s->done_items++;
        if (!s->quiet && res->made) {
            char name[64];
            wf_survey_item_name(s->ctx, i, name, sizeof name);
            fprintf(stderr, "wfisim survey: [%zu/%zu] %s %s MJD %.5f%s on rank %d (%.0f s)\n", s->done_items, s->n,
                    name, res->row.filter, res->row.mjd, wf_survey_item_note(res), rank, difftime(time(NULL), s->t0));
        }
    }
    pthread_mutex_unlock(&s->mu);
}

static void *local_worker(void *arg)
{
    shared *s = arg;
    for (long long i; (i = take(s, 0)) >= 0;) {
        wf_survey_item_result res;
        int crashed;
        wf_status st = wf_survey_make_item_isolated(s->ctx, (size_t)i, &res, &crashed);
        record(s, 0, (size_t)i, st, crashed, st ? wf_error_message() : "", &res);
        if (st && !crashed) break;
    }
    pthread_mutex_lock(&s->mu);
    s->local_done = 1;
    pthread_mutex_unlock(&s->mu);
    return NULL;
}

/* Rank 0: answers every worker's report with the next item (or -1: stop) until every worker
 * has been told to stop and its own worker thread (if any) is done. */
static wf_status dispatch(shared *s, int nranks, int threaded)
{
    pthread_t t;
    int have_thread = threaded && pthread_create(&t, NULL, local_worker, s) == 0;
    if (!have_thread && nranks == 1) local_worker(s);
    int active = nranks - 1;
    report r;
    for (;;) {
        pthread_mutex_lock(&s->mu);
        int local_done = have_thread ? s->local_done : 1;
        pthread_mutex_unlock(&s->mu);
        if (!active && local_done) break;
        int flag = 0;
        MPI_Status ms;
        if (active) MPI_Iprobe(MPI_ANY_SOURCE, TAG_REPORT, MPI_COMM_WORLD, &flag, &ms);
        if (!flag) {
            nap();
            continue;
        }
        MPI_Recv(&r, (int)sizeof r, MPI_BYTE, ms.MPI_SOURCE, TAG_REPORT, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
        if (r.has_result) record(s, ms.MPI_SOURCE, (size_t)r.item, r.status, r.crashed, r.message, &r.res);
        int64_t next = take(s, ms.MPI_SOURCE);
        MPI_Send(&next, 1, MPI_INT64_T, ms.MPI_SOURCE, TAG_WORK, MPI_COMM_WORLD);
        if (next < 0) active--;
    }
    if (have_thread) pthread_join(t, NULL);
    return s->st;
}

/* Ranks > 0: report, receive an item, make it, until told to stop. An item whose process
 * crashed is rank 0's to report (the rank goes on); another failure is the rank's own too. */
static wf_status work(wf_survey_ctx *ctx)
{
    report r;
    memset(&r, 0, sizeof r);
    wf_status mine = WF_OK;
    for (;;) {
        MPI_Send(&r, (int)sizeof r, MPI_BYTE, 0, TAG_REPORT, MPI_COMM_WORLD);
        int64_t i;
        MPI_Recv(&i, 1, MPI_INT64_T, 0, TAG_WORK, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
        if (i < 0) break;
        int crashed;
        wf_status st = wf_survey_make_item_isolated(ctx, (size_t)i, &r.res, &crashed);
        r.item = i;
        r.has_result = 1;
        r.status = st;
        r.crashed = crashed;
        snprintf(r.message, sizeof r.message, "%s", st ? wf_error_message() : "");
        if (st && !crashed && !mine) mine = wf_error(st, "%s", r.message);
    }
    return mine;
}

/* Completes a non-blocking collective without spinning (blocking ones may busy-poll). */
static void quiet_wait(MPI_Request *rq)
{
    int done = 0;
    while (MPI_Test(rq, &done, MPI_STATUS_IGNORE) == MPI_SUCCESS && !done) nap();
}

/* Every rank waits here for the others (MPI_Finalize may busy-poll). */
static void quiet_barrier(void)
{
    MPI_Request rq;
    MPI_Ibarrier(MPI_COMM_WORLD, &rq);
    quiet_wait(&rq);
}

/* Rank 0 alone checks every item's product against this run's inputs (wf_survey_check_inputs), so
 * that a refusal names the first changed product in plan order and comes before any rank
 * renders; the verdict (refused or not, and one state byte per item) then goes to every rank,
 * which waits for it asleep. */
static wf_status check_on_rank0(wf_survey_ctx *ctx, size_t n, int rank)
{
    int32_t refused = 0;
    wf_status st = WF_OK;
    if (rank == 0) {
        st = wf_survey_check_inputs(ctx);
        refused = (int32_t)st;
    }
    MPI_Request rq;
    MPI_Ibcast(&refused, 1, MPI_INT32_T, 0, MPI_COMM_WORLD, &rq);
    quiet_wait(&rq);
    if (refused) return rank == 0 ? st : wf_error((wf_status)refused, "rank 0 did not start the run");
    MPI_Ibcast(wf_survey_item_states(ctx), (int)n, MPI_BYTE, 0, MPI_COMM_WORLD, &rq);
    quiet_wait(&rq);
    return WF_OK;
}

wf_status wf_survey_run_mpi(const wf_config *cfg, const wf_survey_run_options *opt, wf_survey_run_stats *stats)
{
    memset(stats, 0, sizeof *stats);
    int provided = 0, rank = 0, nranks = 1;
    /* the items are made in forked processes that never call MPI: nothing to warn about
     * (the user's own setting is kept) */
    setenv("OMPI_MCA_mpi_warn_on_fork", "0", 0);
    if (MPI_Init_thread(NULL, NULL, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS)
        return wf_error(WF_ERR_IO, "MPI_Init_thread failed");
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &nranks);
    wf_survey_ctx *ctx = NULL;
    size_t n = 0;
    wf_status st = wf_survey_begin(cfg, opt, &ctx, &n);
    /* Every rank read the same plan; if any could not, none starts (that rank says why). */
    int bad = st != WF_OK, any_bad = 0;
    MPI_Allreduce(&bad, &any_bad, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
    if (any_bad && !st) {
        st = wf_error(WF_ERR_IO, "another rank could not start the run");
        stats->silent = rank > 0; /* rank 0 says so; the rank that failed says why */
    }
    if (!st && (st = check_on_rank0(ctx, n, rank)) && rank > 0) stats->silent = 1; /* rank 0 says why */
    if (!st && rank == 0) {
        shared s;
        memset(&s, 0, sizeof s);
        pthread_mutex_init(&s.mu, NULL);
        s.ctx = ctx;
        s.n = n;
        s.quiet = cfg->quiet;
        s.t0 = time(NULL);
        s.res = calloc(n, sizeof *s.res);
        s.lost = calloc(n, 1);
        s.cur = calloc((size_t)nranks, sizeof *s.cur);
        s.end = calloc((size_t)nranks, sizeof *s.end);
        if (!s.res || !s.lost || !s.cur || !s.end ||
            wf_survey_walks(ctx, (size_t)nranks, &s.order, &s.start, &s.nwalks)) { /* the workers must still be told to stop */
            s.stop = 1;
            s.st = WF_ERR_NOMEM;
            snprintf(s.message, sizeof s.message, "out of memory for %zu results", n);
        }
        st = dispatch(&s, nranks, provided >= MPI_THREAD_FUNNELED);
        if (s.nlost) st = wf_survey_lost(ctx, s.lost, st ? s.message : "");
        else if (st) st = wf_error(st, "%s", s.message);
        else if (s.done_items != n) st = wf_error(WF_ERR_IO, "%zu of %zu items reported", s.done_items, n);
        if (s.res && s.lost) st = st ? wf_survey_end_failed(ctx, s.res, st, stats) : wf_survey_end(ctx, s.res, stats);
        stats->silent = 0;
        free(s.res);
        free(s.lost);
        free(s.cur);
        free(s.end);
        free(s.order);
        free(s.start);
        pthread_mutex_destroy(&s.mu);
    } else if (!st) {
        st = work(ctx);
        stats->silent = !st; /* a rank's own failure is printed by it too */
    }
    wf_survey_free(ctx);
    /* the error message is kept across the barrier and MPI_Finalize (neither sets one) */
    quiet_barrier();
    MPI_Finalize();
    return st;
}
