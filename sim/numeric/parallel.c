#include "sim/numeric/parallel.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>

typedef struct loop {
    int ntasks;
    wf_parallel_fn fn;
    void *ctx;
    atomic_int next;
    pthread_mutex_t lock;
    int failed_task; /* lowest failing task so far; ntasks: none */
    wf_status st;
    char message[1024];
} loop;

typedef struct slot_arg {
    loop *l;
    int slot;
} slot_arg;

static void run_slot(loop *l, int slot)
{
    for (;;) {
        int t = atomic_fetch_add(&l->next, 1);
        if (t >= l->ntasks) return;
        pthread_mutex_lock(&l->lock);
        int stop = t > l->failed_task; /* a lower task failed: its error is the answer */
        pthread_mutex_unlock(&l->lock);
        if (stop) return;
        wf_status st = l->fn(l->ctx, t, slot);
        if (st) {
            pthread_mutex_lock(&l->lock);
            if (t < l->failed_task) {
                l->failed_task = t;
                l->st = st;
                snprintf(l->message, sizeof l->message, "%s", wf_error_message());
            }
            pthread_mutex_unlock(&l->lock);
        }
    }
}

static void *slot_main(void *arg)
{
    slot_arg *a = arg;
    run_slot(a->l, a->slot);
    return NULL;
}

wf_status wf_parallel_for(int ntasks, int threads, wf_parallel_fn fn, void *ctx)
{
    if (ntasks <= 0) return WF_OK;
    if (threads > ntasks) threads = ntasks;
    if (threads > WF_PARALLEL_MAX_THREADS) threads = WF_PARALLEL_MAX_THREADS;
    if (threads <= 1) {
        for (int t = 0; t < ntasks; t++) {
            wf_status st = fn(ctx, t, 0);
            if (st) return st;
        }
        return WF_OK;
    }
    loop l = {.ntasks = ntasks, .fn = fn, .ctx = ctx, .failed_task = ntasks, .st = WF_OK};
    atomic_init(&l.next, 0);
    pthread_mutex_init(&l.lock, NULL);
    pthread_t th[WF_PARALLEL_MAX_THREADS];
    slot_arg args[WF_PARALLEL_MAX_THREADS];
    int started = 0;
    for (int s = 1; s < threads; s++) {
        args[s] = (slot_arg){&l, s};
        if (pthread_create(&th[s], NULL, slot_main, &args[s]) != 0) break;
        started = s;
    }
    run_slot(&l, 0);
    for (int s = 1; s <= started; s++) pthread_join(th[s], NULL);
    pthread_mutex_destroy(&l.lock);
    if (l.st) return wf_error(l.st, "%s", l.message);
    return WF_OK;
}
