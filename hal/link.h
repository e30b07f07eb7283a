/* Output link: where the firmware's packets go. One send() carries one whole packet, so
 * packets from several firmware instances never interleave. Implementations: an in-process
 * memory buffer, and a stdio stream (a file, or stdout for `wfisim expose | wfisim assemble -`).
 * Both serialise send() with a mutex so that several readout threads can share one link. */
#ifndef WF_LINK_H
#define WF_LINK_H

#include <stddef.h>
#include <stdio.h>
#include <pthread.h>
#include "hal/status.h"

typedef struct wf_link {
    void *ctx;
    wf_status (*send)(void *ctx, const void *packet, size_t len);
} wf_link;

static inline wf_status wf_link_send(const wf_link *link, const void *packet, size_t len)
{
    return link->send(link->ctx, packet, len);
}

typedef struct wf_link_memory {
    unsigned char *data;
    size_t len, cap;
    pthread_mutex_t lock;
} wf_link_memory;

wf_status wf_link_memory_open(wf_link_memory *m, wf_link *out);
void wf_link_memory_close(wf_link_memory *m);

typedef struct wf_link_stream {
    FILE *file;
    const char *name;
    pthread_mutex_t lock;
} wf_link_stream;

wf_status wf_link_stream_open(wf_link_stream *s, FILE *file, const char *name, wf_link *out);
void wf_link_stream_close(wf_link_stream *s);

#endif
