#include "hal/link.h"

#include "hal/arena.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

static wf_status memory_send(void *ctx, const void *packet, size_t len)
{
    wf_link_memory *m = ctx;
    wf_status st = WF_OK;
    pthread_mutex_lock(&m->lock);
    if (m->len + len > m->cap) {
        size_t cap = m->cap ? m->cap : 1 << 20;
        while (cap < m->len + len) cap *= 2;
        unsigned char *grown = realloc(m->data, cap);
        if (!grown) {
            st = wf_error(WF_ERR_NOMEM, "link: cannot grow the in-memory stream to %zu bytes", cap);
            goto out;
        }
        m->data = grown;
        m->cap = cap;
    }
    memcpy(m->data + m->len, packet, len);
    m->len += len;
out:
    pthread_mutex_unlock(&m->lock);
    return st;
}

wf_status wf_link_memory_open(wf_link_memory *m, wf_link *out)
{
    memset(m, 0, sizeof *m);
    pthread_mutex_init(&m->lock, NULL);
    out->ctx = m;
    out->send = memory_send;
    return WF_OK;
}

void wf_link_memory_close(wf_link_memory *m)
{
    free(m->data);
    m->data = NULL;
    m->len = m->cap = 0;
    pthread_mutex_destroy(&m->lock);
}

static wf_status stream_send(void *ctx, const void *packet, size_t len)
{
    wf_link_stream *s = ctx;
    wf_status st = WF_OK;
    pthread_mutex_lock(&s->lock);
    if (fwrite(packet, 1, len, s->file) != len)
        st = wf_error(WF_ERR_IO, "%s: write failed: %s", s->name, strerror(errno));
    pthread_mutex_unlock(&s->lock);
    return st;
}

wf_status wf_link_stream_open(wf_link_stream *s, FILE *file, const char *name, wf_link *out)
{
    s->file = file;
    s->name = name;
    pthread_mutex_init(&s->lock, NULL);
    out->ctx = s;
    out->send = stream_send;
    return WF_OK;
}

void wf_link_stream_close(wf_link_stream *s)
{
    pthread_mutex_destroy(&s->lock);
}

/* ------------------------------------------------------------------ in-process pipe */

static size_t min_size(size_t a, size_t b) { return a < b ? a : b; }

static wf_status pipe_send(void *ctx, const void *packet, size_t len)
{
    wf_link_pipe *p = ctx;
    const unsigned char *src = packet;
    wf_status st = WF_OK;
    pthread_mutex_lock(&p->send_lock);
    pthread_mutex_lock(&p->lock);
    while (len > 0) {
        /* wait for a quarter of the ring (or all that is left), so that a full ring is not
         * refilled a header at a time */
        size_t enough = min_size(len, p->cap / 4);
        while (!p->read_closed && p->cap - p->len < enough) {
            p->room = enough;
            pthread_cond_wait(&p->writable, &p->lock);
        }
        p->room = 0;
        if (p->read_closed) {
            p->refused = 1;
            st = wf_error(WF_ERR_IO, "%s: " WF_LINK_PIPE_REFUSED, p->name);
            break;
        }
        size_t n = min_size(len, p->cap - p->len), tail = (p->head + p->len) % p->cap;
        size_t first = min_size(n, p->cap - tail);
        /* the copy runs unlocked: the reader touches only [head, head + len), and only this
         * sender (under send_lock) writes beyond it */
        pthread_mutex_unlock(&p->lock);
        memcpy(p->ring + tail, src, first);
        memcpy(p->ring, src + first, n - first);
        pthread_mutex_lock(&p->lock);
        p->len += n;
        src += n;
        len -= n;
        if (p->want && p->len >= p->want) pthread_cond_signal(&p->readable);
    }
    pthread_mutex_unlock(&p->lock);
    pthread_mutex_unlock(&p->send_lock);
    return st;
}

wf_status wf_link_pipe_open(wf_link_pipe *p, size_t cap, const char *name, wf_link *out)
{
    memset(p, 0, sizeof *p);
    if (cap < 4096) cap = 4096;
    if (!(p->ring = wf_arena_host_realloc(NULL, 0, cap)))
        return wf_error(WF_ERR_NOMEM, "%s: cannot allocate a %zu-byte pipe", name, cap);
    p->cap = cap;
    p->name = name;
    pthread_mutex_init(&p->lock, NULL);
    pthread_mutex_init(&p->send_lock, NULL);
    pthread_cond_init(&p->readable, NULL);
    pthread_cond_init(&p->writable, NULL);
    out->ctx = p;
    out->send = pipe_send;
    return WF_OK;
}

void wf_link_pipe_close_write(wf_link_pipe *p)
{
    pthread_mutex_lock(&p->lock);
    p->write_closed = 1;
    pthread_cond_broadcast(&p->readable);
    pthread_mutex_unlock(&p->lock);
}

void wf_link_pipe_close_read(wf_link_pipe *p)
{
    pthread_mutex_lock(&p->lock);
    p->read_closed = 1;
    pthread_cond_broadcast(&p->writable);
    pthread_mutex_unlock(&p->lock);
}

size_t wf_link_pipe_read(wf_link_pipe *p, void *buf, size_t n)
{
    unsigned char *dst = buf;
    size_t done = 0;
    pthread_mutex_lock(&p->lock);
    while (done < n) {
        /* at most half the ring: a writer waiting for a quarter of it must be able to add
         * what this reader waits for */
        size_t need = min_size(n - done, p->cap / 2);
        while (p->len < need && !p->write_closed) {
            p->want = need;
            pthread_cond_wait(&p->readable, &p->lock);
        }
        p->want = 0;
        if (p->len == 0) break; /* closed and drained */
        size_t k = min_size(n - done, p->len), first = min_size(k, p->cap - p->head);
        pthread_mutex_unlock(&p->lock);
        memcpy(dst + done, p->ring + p->head, first);
        memcpy(dst + done + first, p->ring, k - first);
        pthread_mutex_lock(&p->lock);
        p->head = (p->head + k) % p->cap;
        p->len -= k;
        done += k;
        if (p->room && p->cap - p->len >= p->room) pthread_cond_signal(&p->writable);
    }
    pthread_mutex_unlock(&p->lock);
    return done;
}

void wf_link_pipe_free(wf_link_pipe *p)
{
    if (!p->ring) return;
    free(p->ring);
    p->ring = NULL;
    pthread_mutex_destroy(&p->lock);
    pthread_mutex_destroy(&p->send_lock);
    pthread_cond_destroy(&p->readable);
    pthread_cond_destroy(&p->writable);
}
