#include "tools/expose.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

typedef struct worker {
    wf_expose_job *job;
    int index;
    void *memory;
    wf_arena arena;
    wf_readout *ro;
    wf_status status;
    char message[1024];
    atomic_int *rows_done;
    atomic_int *failed;
} worker;

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Instance i takes a contiguous run of tiles, so a scene renderer behind it draws an object
 * spanning several tiles once, not once per thread. */
static void tile_range(int ntiles, int threads, int i, int *first, int *end)
{
    *first = (int)((long)ntiles * i / threads);
    *end = (int)((long)ntiles * (i + 1) / threads);
}

static void *work(void *arg)
{
    worker *w = arg;
    int first, end;
    tile_range(wf_readout_tile_count(w->ro), w->job->threads, w->index, &first, &end);
    for (int t = first; t < end && !atomic_load(w->failed); t++) {
        w->status = wf_readout_run_tile(w->ro, t);
        if (w->status) {
            snprintf(w->message, sizeof w->message, "%s", wf_error_message());
            atomic_store(w->failed, 1);
            break;
        }
        int y0 = t * w->job->ro.tile_rows, rows = w->job->ro.nrows - y0;
        atomic_fetch_add(w->rows_done, rows < w->job->ro.tile_rows ? rows : w->job->ro.tile_rows);
    }
    return NULL;
}

static void show_progress(int done, int total, double t0)
{
    double el = now() - t0, rate = el > 0 ? done / el : 0;
    double left = rate > 0 ? (total - done) / rate : 0;
    fprintf(stderr, "\r  rows %5d/%d  %6.0f rows/s  %5.1f s left ", done, total, rate, left);
    fflush(stderr);
}

wf_status wf_expose_run(wf_expose_job *job)
{
    int T = job->threads < 1 ? 1 : job->threads;
    job->threads = T;
    size_t need;
    wf_status st = wf_readout_arena_need(&job->ro, &job->clock, &need);
    if (st) return st;
    job->arena_bytes = need;
    worker *ws = calloc((size_t)T, sizeof *ws);
    if (!ws) return wf_error(WF_ERR_NOMEM, "cannot allocate %d workers", T);
    atomic_int rows_done = 0, failed = 0;
    int created = 0;
    for (int i = 0; i < T; i++) {
        worker *w = &ws[i];
        w->job = job;
        w->index = i;
        w->rows_done = &rows_done;
        w->failed = &failed;
        /* The host reserves each instance's whole budget once; the firmware never asks again. */
        w->memory = wf_arena_host_alloc(need);
        if (!w->memory) { st = wf_error(WF_ERR_NOMEM, "cannot reserve %zu bytes for readout %d", need, i); goto out; }
        wf_arena_init(&w->arena, w->memory, need, "readout arena");
        if ((st = wf_readout_create(&job->ro, &job->clock, &job->scenes[i], &job->noise, job->link,
                                    &w->arena, &w->ro)))
            goto out;
    }
    if ((st = wf_readout_send_meta(ws[0].ro, job->meta_extra))) goto out;
    double t0 = now();
    pthread_t *th = calloc((size_t)T, sizeof *th);
    if (!th) { st = wf_error(WF_ERR_NOMEM, "cannot allocate threads"); goto out; }
    for (int i = 1; i < T; i++) {
        if (pthread_create(&th[i], NULL, work, &ws[i]) != 0) {
            atomic_store(&failed, 1);
            st = wf_error(WF_ERR_INTERNAL, "cannot start readout thread %d", i);
            break;
        }
        created = i;
    }
    if (job->progress && created == T - 1) {
        /* the main thread runs instance 0 and reports between its tiles */
        int first, end;
        tile_range(wf_readout_tile_count(ws[0].ro), T, 0, &first, &end);
        for (int t = first; t < end && !atomic_load(&failed); t++) {
            ws[0].status = wf_readout_run_tile(ws[0].ro, t);
            if (ws[0].status) {
                snprintf(ws[0].message, sizeof ws[0].message, "%s", wf_error_message());
                atomic_store(&failed, 1);
                break;
            }
            int y0 = t * job->ro.tile_rows, rows = job->ro.nrows - y0;
            atomic_fetch_add(&rows_done, rows < job->ro.tile_rows ? rows : job->ro.tile_rows);
            show_progress(atomic_load(&rows_done), job->ro.nrows, t0);
        }
    } else if (created == T - 1) {
        work(&ws[0]);
    }
    for (int i = 1; i <= created; i++) pthread_join(th[i], NULL);
    free(th);
    if (job->progress) {
        show_progress(atomic_load(&rows_done), job->ro.nrows, t0);
        fprintf(stderr, "\n");
    }
    if (!st)
        for (int i = 0; i < T; i++)
            if (ws[i].status) { st = wf_error(ws[i].status, "%s", ws[i].message); break; }
    if (!st) st = wf_readout_send_end(ws[0].ro);
out:
    job->arena_high_water = 0;
    for (int i = 0; i < T; i++) {
        if (ws[i].arena.high_water > job->arena_high_water) job->arena_high_water = ws[i].arena.high_water;
        wf_readout_destroy(ws[i].ro);
        free(ws[i].memory);
    }
    free(ws);
    return st;
}
