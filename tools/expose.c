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
    struct tile_runs *runs;
    int next, end;      /* this instance's run: tiles [next, end) not yet started */
    double t0;          /* start, for the progress line */
} worker;

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void show_progress(int done, int total, double t0)
{
    double el = now() - t0, rate = el > 0 ? done / el : 0;
    double left = rate > 0 ? (total - done) / rate : 0;
    fprintf(stderr, "\r  rows %5d/%d  %6.0f rows/s  %5.1f s left ", done, total, rate, left);
    fflush(stderr);
}

/* Tiles go out in contiguous runs: instance i starts with the i-th run, so that a scene
 * renderer behind it draws an object spanning several tiles once, not once per thread. An
 * instance whose run is done takes the back half of the longest run left (the objects that
 * straddle the new boundary are drawn by both), so a scene crowded on one part of the SCA,
 * or a core shared with the assembler, does not leave a thread idle. Which instance runs a
 * tile changes no byte of the product. */
typedef struct tile_runs {
    pthread_mutex_t lock; /* guards every worker's next and end */
    worker *ws;
    int n;
} tile_runs;

static int next_tile(tile_runs *q, worker *w)
{
    pthread_mutex_lock(&q->lock);
    if (w->next >= w->end) {
        worker *v = NULL;
        int most = 0;
        for (int k = 0; k < q->n; k++)
            if (q->ws[k].end - q->ws[k].next > most) most = q->ws[k].end - q->ws[k].next, v = &q->ws[k];
        if (v) {
            int mid = most == 1 ? v->next : v->end - most / 2;
            w->next = mid;
            w->end = v->end;
            v->end = mid;
        }
    }
    int t = w->next < w->end ? w->next++ : -1;
    pthread_mutex_unlock(&q->lock);
    return t;
}

static void *work(void *arg)
{
    worker *w = arg;
    for (int t; !atomic_load(w->failed) && (t = next_tile(w->runs, w)) >= 0;) {
        w->status = wf_readout_run_tile(w->ro, t);
        if (w->status) {
            snprintf(w->message, sizeof w->message, "%s", wf_error_message());
            int none = 0; /* the first instance to fail, in time, names the cause */
            atomic_compare_exchange_strong(w->failed, &none, w->index + 1);
            break;
        }
        int y0 = t * w->job->ro.tile_rows, rows = w->job->ro.nrows - y0;
        atomic_fetch_add(w->rows_done, rows < w->job->ro.tile_rows ? rows : w->job->ro.tile_rows);
        if (w->index == 0 && w->job->progress) show_progress(atomic_load(w->rows_done), w->job->ro.nrows, w->t0);
    }
    return NULL;
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
    tile_runs runs = {.ws = ws, .n = T};
    pthread_mutex_init(&runs.lock, NULL);
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
    int ntiles = wf_readout_tile_count(ws[0].ro);
    for (int i = 0; i < T; i++) {
        ws[i].next = (int)((long)ntiles * i / T);
        ws[i].end = (int)((long)ntiles * (i + 1) / T);
        ws[i].runs = &runs;
        ws[i].t0 = t0;
    }
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
    if (created == T - 1) work(&ws[0]); /* the main thread runs instance 0 (and shows progress) */
    for (int i = 1; i <= created; i++) pthread_join(th[i], NULL);
    free(th);
    if (job->progress) {
        show_progress(atomic_load(&rows_done), job->ro.nrows, t0);
        fprintf(stderr, "\n");
    }
    /* the first failure in time: a later one may only be its consequence (a link closed
     * because its reader gave up after the first) */
    int first = atomic_load(&failed);
    if (!st && first > 0 && ws[first - 1].status) st = wf_error(ws[first - 1].status, "%s", ws[first - 1].message);
    if (!st) st = wf_readout_send_end(ws[0].ro);
out:
    job->arena_high_water = 0;
    for (int i = 0; i < T; i++) {
        if (ws[i].arena.high_water > job->arena_high_water) job->arena_high_water = ws[i].arena.high_water;
        wf_readout_destroy(ws[i].ro);
        free(ws[i].memory);
    }
    free(ws);
    pthread_mutex_destroy(&runs.lock);
    return st;
}
