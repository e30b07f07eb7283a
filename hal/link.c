#include "hal/link.h"

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
        st = wf_error(WF_ERR_IO, "%s: write failed (disk full or pipe closed?)", s->name);
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
