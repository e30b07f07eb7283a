/* Output link: where the firmware's packets go. One send() carries one whole packet, so
 * packets from several firmware instances never interleave. Implementations: an in-process
 * memory buffer, a stdio stream (a file, or stdout for `wfisim expose | wfisim assemble -`)
 * and an in-process pipe to a reader thread. Each serialises send() with a mutex so that
 * several readout threads can share one link. */
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

/* An in-process pipe: send() copies each packet into a ring of host memory that a reader
 * thread drains with wf_link_pipe_read. It stands where an OS pipe stood between the readout
 * and an assembler thread of the same process: the same bytes, without two system calls and
 * two kernel copies per 64 KiB, and a wake-up per quarter ring instead of per 64 KiB. A
 * packet larger than the ring passes through it in pieces; senders queue on their own lock,
 * so a packet is never interleaved with another. */
typedef struct wf_link_pipe {
    unsigned char *ring;
    size_t cap, head, len;      /* unread bytes: [head, head + len) modulo cap */
    size_t want;                /* bytes the waiting reader needs (0: not waiting) */
    size_t room;                /* free bytes the waiting sender needs (0: not waiting) */
    int write_closed, read_closed;
    int refused;                /* a send failed because the reader had closed */
    const char *name;
    pthread_mutex_t lock, send_lock;
    pthread_cond_t readable, writable;
} wf_link_pipe;

/* The words of a refused send's message (after the pipe's name), so that a caller can tell
 * a failure caused by the reader's stop from one of the sender's own. */
#define WF_LINK_PIPE_REFUSED "the reader has stopped"

wf_status wf_link_pipe_open(wf_link_pipe *p, size_t cap, const char *name, wf_link *out);
/* The writer is done: the reader sees the end of the stream once the ring is empty. */
void wf_link_pipe_close_write(wf_link_pipe *p);
/* The reader is done or gave up: from now on a send fails at once (and sets p->refused)
 * instead of waiting for room that will never come. */
void wf_link_pipe_close_read(wf_link_pipe *p);
/* Copies n bytes into buf, waiting for them; fewer only at the end of the stream. Returns
 * the count. */
size_t wf_link_pipe_read(wf_link_pipe *p, void *buf, size_t n);
void wf_link_pipe_free(wf_link_pipe *p);

#endif
