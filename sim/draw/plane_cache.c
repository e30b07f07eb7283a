#include "sim/draw/plane_cache.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <libdeflate.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "hal/file.h"

#define TEXT 4096 /* the text header; then a CRC-32 per row of the plane, then of the layer */
#define MAGIC "wfisim plane 2\n"
#define SUFFIX ".plane"
#define STALE_SECONDS (24 * 3600) /* a temporary file untouched this long was abandoned */

struct wf_plane_cache {
    char dir[4096];
    double max_bytes;
    pthread_mutex_t lock;
    unsigned long serial; /* temporary names within this process */
    wf_plane_cache_stats stats;
};

struct wf_plane_entry {
    wf_plane_cache *c;
    int fd, found, ncols, nrows, layer, failed, created;
    char path[4200], tmp[4400];
    char note[WF_PLANE_NOTE_MAX];
    pthread_mutex_t lock;
    unsigned char *seen; /* rows written (being written) */
    long nseen;
    uint32_t *crc;       /* per row, the plane's then the layer's (found: as stored) */
};

static size_t rows_kept(const wf_plane_entry *e) { return (size_t)(e->layer ? 2 : 1) * (size_t)e->nrows; }

/* The header: the text, then the rows' CRC-32s, to a whole 4096 bytes. */
static off_t header_bytes(const wf_plane_entry *e)
{
    return (off_t)((TEXT + rows_kept(e) * sizeof(uint32_t) + 4095) / 4096 * 4096);
}

wf_status wf_plane_cache_open(const char *dir, double max_bytes, wf_plane_cache **out)
{
    *out = NULL;
    if (!dir || !dir[0]) return wf_error(WF_ERR_INPUT, "scene cache: no folder given");
    if (strlen(dir) >= 4000) return wf_error(WF_ERR_INPUT, "scene cache: folder name too long");
    if (!(max_bytes >= 0.0)) return wf_error(WF_ERR_RANGE, "scene cache: room %g bytes", max_bytes);
    wf_status st = wf_file_make_dir(dir);
    if (st) return wf_error(st, "scene cache %s: %s", dir, wf_error_message());
    struct stat sb;
    if (stat(dir, &sb) != 0 || !S_ISDIR(sb.st_mode))
        return wf_error(WF_ERR_IO, "scene cache %s: not a folder", dir);
    wf_plane_cache *c = calloc(1, sizeof *c);
    if (!c) return wf_error(WF_ERR_NOMEM, "scene cache: out of memory");
    snprintf(c->dir, sizeof c->dir, "%s", dir);
    c->max_bytes = max_bytes;
    pthread_mutex_init(&c->lock, NULL);
    *out = c;
    return WF_OK;
}

void wf_plane_cache_close(wf_plane_cache *c)
{
    if (!c) return;
    pthread_mutex_destroy(&c->lock);
    free(c);
}

void wf_plane_cache_get_stats(wf_plane_cache *c, wf_plane_cache_stats *out)
{
    pthread_mutex_lock(&c->lock);
    *out = c->stats;
    pthread_mutex_unlock(&c->lock);
}

static void not_kept(wf_plane_cache *c, const char *what, const char *path, int err)
{
    pthread_mutex_lock(&c->lock);
    if (!c->stats.reason[0])
        snprintf(c->stats.reason, sizeof c->stats.reason, "%s %.300s: %.100s", what, path, strerror(err));
    c->stats.not_kept++;
    pthread_mutex_unlock(&c->lock);
}

static void header_text(const wf_plane_entry *e, const char *key, char *buf)
{
    memset(buf, 0, TEXT);
    snprintf(buf, TEXT, MAGIC "key = %s\nncols = %d\nnrows = %d\nlayer = %d\nfloat = %zu\nnote = %s\n", key,
             e->ncols, e->nrows, e->layer, sizeof(float), e->note);
}

static off_t file_bytes(const wf_plane_entry *e)
{
    return header_bytes(e) + (off_t)rows_kept(e) * (off_t)e->ncols * (off_t)sizeof(float);
}

static int write_all(int fd, const void *buf, size_t n, off_t at)
{
    const char *p = buf;
    while (n) {
        ssize_t w = pwrite(fd, p, n, at);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return w < 0 ? errno : ENOSPC;
        p += w, n -= (size_t)w, at += w;
    }
    return 0;
}

static int read_all(int fd, void *buf, size_t n, off_t at)
{
    char *p = buf;
    while (n) {
        ssize_t r = pread(fd, p, n, at);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) return r < 0 ? errno : EIO;
        p += r, n -= (size_t)r, at += r;
    }
    return 0;
}

static uint32_t row_crc(const float *r, int n) { return (uint32_t)libdeflate_crc32(0, r, (size_t)n * sizeof *r); }

/* An existing file under the key: used only if its header is the one this entry would write
 * (but for the note) and its size is whole. */
static int matches(wf_plane_entry *e, const char *key, int fd)
{
    struct stat sb;
    char *have = malloc(TEXT), *want = malloc(TEXT);
    int ok = have && want && fstat(fd, &sb) == 0 && sb.st_size == file_bytes(e) && !read_all(fd, have, TEXT, 0);
    if (ok) {
        header_text(e, key, want);
        const char *n = strstr(want, "note = ");
        size_t lead = (size_t)(n - want) + 7;
        const char *end = memchr(have + lead, '\n', TEXT - lead);
        ok = !memcmp(have, want, lead) && end;
        if (ok) {
            size_t len = (size_t)(end - (have + lead));
            if (len >= sizeof e->note) len = sizeof e->note - 1;
            memcpy(e->note, have + lead, len);
            e->note[len] = '\0';
            ok = !read_all(fd, e->crc, rows_kept(e) * sizeof *e->crc, TEXT);
        }
    }
    free(have);
    free(want);
    return ok;
}

void wf_plane_entry_close(wf_plane_entry *e);

static wf_status entry_open(wf_plane_cache *c, const char *key, int ncols, int nrows, int layer, int create,
                            wf_plane_entry **out, int *found)
{
    *out = NULL;
    *found = 0;
    if (strlen(key) != 64 || strspn(key, "0123456789abcdef") != 64)
        return wf_error(WF_ERR_INTERNAL, "scene cache: key \"%s\" is not 64 hex digits", key);
    if (ncols < 1 || nrows < 1) return wf_error(WF_ERR_RANGE, "scene cache: %d x %d pixels", ncols, nrows);
    wf_plane_entry *e = calloc(1, sizeof *e);
    if (e) e->layer = layer != 0, e->nrows = nrows;
    if (!e || !(e->seen = calloc((size_t)nrows, 1)) || !(e->crc = calloc(rows_kept(e), sizeof *e->crc))) {
        if (e) free(e->seen);
        free(e);
        return wf_error(WF_ERR_NOMEM, "scene cache: out of memory");
    }
    e->c = c;
    e->ncols = ncols;
    e->fd = -1;
    pthread_mutex_init(&e->lock, NULL);
    snprintf(e->path, sizeof e->path, "%s/%s" SUFFIX, c->dir, key);
    int fd = open(e->path, O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
        if (matches(e, key, fd)) {
            futimens(fd, NULL); /* used now: the last to be evicted */
            e->fd = fd;
            e->found = *found = 1;
            pthread_mutex_lock(&c->lock);
            c->stats.hits++;
            pthread_mutex_unlock(&c->lock);
            *out = e;
            return WF_OK;
        }
        close(fd);
        pthread_mutex_lock(&c->lock);
        c->stats.unusable++;
        pthread_mutex_unlock(&c->lock);
    }
    if (!create) {
        wf_plane_entry_close(e);
        return WF_OK;
    }
    e->note[0] = '\0';
    /* a name no other writer has, whichever host or process (the folder may be shared) */
    char host[64] = "";
    gethostname(host, sizeof host - 1);
    for (char *h = host; *h; h++)
        if (*h == '/') *h = '_';
    int err = EEXIST;
    for (int tries = 0; tries < 16 && err == EEXIST; tries++) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        pthread_mutex_lock(&c->lock);
        unsigned long serial = c->serial++;
        pthread_mutex_unlock(&c->lock);
        snprintf(e->tmp, sizeof e->tmp, "%s.tmp.%.60s.%ld.%lu.%09ld", e->path, host, (long)getpid(), serial,
                 (long)ts.tv_nsec);
        e->fd = open(e->tmp, O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
        err = e->fd < 0 ? errno : 0;
    }
    e->created = !err;
    if (!err && ftruncate(e->fd, file_bytes(e)) != 0) err = errno; /* rows of zeros stay holes */
    if (err) {
        not_kept(c, "cannot write", e->tmp, err);
        e->failed = 1;
    }
    *out = e;
    return WF_OK;
}

wf_status wf_plane_entry_open(wf_plane_cache *c, const char *key, int ncols, int nrows, int layer,
                              wf_plane_entry **out, int *found)
{
    return entry_open(c, key, ncols, nrows, layer, 1, out, found);
}

wf_status wf_plane_entry_find(wf_plane_cache *c, const char *key, int ncols, int nrows, int layer,
                              wf_plane_entry **out)
{
    int found;
    return entry_open(c, key, ncols, nrows, layer, 0, out, &found);
}

wf_status wf_plane_entry_get(void *entry, int y0, int y1, int ncols, float *plane, float *layer)
{
    wf_plane_entry *e = entry;
    if (!e->found || ncols != e->ncols || y0 < 0 || y1 > e->nrows || y1 < y0 || (layer && !e->layer))
        return wf_error(WF_ERR_INTERNAL, "scene cache %s: rows %d-%d of %d x %d asked%s", e->path, y0, y1, ncols,
                        e->nrows, layer && !e->layer ? " with a layer it does not have" : "");
    size_t n = (size_t)(y1 - y0) * (size_t)ncols * sizeof(float);
    off_t at = header_bytes(e) + (off_t)y0 * ncols * (off_t)sizeof(float);
    int err = plane ? read_all(e->fd, plane, n, at) : 0;
    if (!err && layer) err = read_all(e->fd, layer, n, at + (off_t)e->nrows * ncols * (off_t)sizeof(float));
    if (err) return wf_error(WF_ERR_IO, "scene cache %s: cannot read rows %d-%d: %s", e->path, y0, y1, strerror(err));
    /* every row against the CRC its writer took: a file damaged after it was kept (a crash
     * before its blocks reached the disk, a bad sector) fails the exposure, never draws it */
    for (int y = y0; y < y1; y++) {
        size_t off = (size_t)(y - y0) * (size_t)ncols;
        int bad = (plane && row_crc(plane + off, ncols) != e->crc[y]) ||
                  (layer && row_crc(layer + off, ncols) != e->crc[e->nrows + y]);
        if (bad) {
            unlink(e->path); /* the next exposure of the scene draws it again */
            return wf_error(WF_ERR_IO, "scene cache %s: row %d does not match its checksum (the file is damaged; "
                            "removed, so that a rerun draws the scene again)", e->path, y);
        }
    }
    return WF_OK;
}


static int zero_row(const float *r, int n)
{
    for (int x = 0; x < n; x++)
        if (r[x] != 0.0f) return 0;
    return 1;
}

void wf_plane_entry_put(void *entry, int y, const float *plane, const float *layer, int ncols)
{
    wf_plane_entry *e = entry;
    const int foreign = e->found || ncols != e->ncols || y < 0 || y >= e->nrows || (!layer != !e->layer);
    pthread_mutex_lock(&e->lock);
    if (foreign) e->failed = 1; /* not this entry's rows: never kept */
    int skip = e->failed || e->seen[y];
    if (!skip) e->seen[y] = 1, e->nseen++;
    pthread_mutex_unlock(&e->lock);
    if (skip) return;
    e->crc[y] = row_crc(plane, ncols); /* its own row: no other thread writes it */
    if (layer) e->crc[e->nrows + y] = row_crc(layer, ncols);
    size_t n = (size_t)ncols * sizeof(float);
    off_t at = header_bytes(e) + (off_t)y * (off_t)n;
    int err = zero_row(plane, ncols) ? 0 : write_all(e->fd, plane, n, at);
    if (!err && layer && !zero_row(layer, ncols)) err = write_all(e->fd, layer, n, at + (off_t)e->nrows * (off_t)n);
    if (err) {
        pthread_mutex_lock(&e->lock);
        int first = !e->failed;
        e->failed = 1;
        pthread_mutex_unlock(&e->lock);
        if (first) not_kept(e->c, "cannot write", e->tmp, err);
    }
}

const char *wf_plane_entry_note(const wf_plane_entry *e) { return e->note; }

static wf_status layer_rows(void *ctx, int y0, int y1, int ncols, float *rate)
{
    return wf_plane_entry_get(ctx, y0, y1, ncols, NULL, rate);
}

void wf_plane_entry_layer_source(wf_plane_entry *e, wf_scene_source *out)
{
    memset(out, 0, sizeof *out);
    out->ctx = e;
    out->fill_rate = layer_rows;
}

void wf_plane_entry_set_note(wf_plane_entry *e, const char *note)
{
    snprintf(e->note, sizeof e->note, "%s", note);
    for (char *p = e->note; *p; p++)
        if (*p == '\n') *p = ' ';
}

typedef struct held { char name[80]; time_t used; long nsec; double bytes; } held;

static int older_first(const void *a, const void *b)
{
    const held *p = a, *q = b;
    if (p->used != q->used) return p->used < q->used ? -1 : 1;
    if (p->nsec != q->nsec) return p->nsec < q->nsec ? -1 : 1;
    return strcmp(p->name, q->name);
}

/* Removes the least recently used entries until the rest fit max_bytes (what they take on
 * disk: holes are free); never `keep`, the one just stored. */
static void evict(wf_plane_cache *c, const char *keep)
{
    DIR *d = opendir(c->dir);
    if (!d) return;
    held *h = NULL;
    size_t n = 0, cap = 0;
    double total = 0.0;
    struct dirent *de;
    const time_t now = time(NULL);
    while ((de = readdir(d))) {
        size_t len = strlen(de->d_name);
        int tmp = len > 64 + strlen(SUFFIX ".tmp.") && !strncmp(de->d_name + 64, SUFFIX ".tmp.", strlen(SUFFIX ".tmp."));
        if (!tmp && (len != 64 + strlen(SUFFIX) || strcmp(de->d_name + 64, SUFFIX))) continue;
        char p[4200];
        struct stat sb;
        snprintf(p, sizeof p, "%s/%s", c->dir, de->d_name);
        if (stat(p, &sb) != 0) continue;
        if (tmp) { /* a writer that died (killed mid-item) left it; one alive renames it in minutes */
            if (sb.st_mtim.tv_sec < now - STALE_SECONDS) unlink(p);
            continue;
        }
        if (n == cap) {
            held *g = realloc(h, (cap = cap ? 2 * cap : 64) * sizeof *h);
            if (!g) break;
            h = g;
        }
        snprintf(h[n].name, sizeof h[n].name, "%s", de->d_name);
        h[n].used = sb.st_mtim.tv_sec;
        h[n].nsec = sb.st_mtim.tv_nsec;
        h[n].bytes = (double)sb.st_blocks * 512.0;
        total += h[n++].bytes;
    }
    closedir(d);
    if (total > c->max_bytes && n) {
        qsort(h, n, sizeof *h, older_first);
        for (size_t i = 0; i < n && total > c->max_bytes; i++) {
            char p[4200];
            snprintf(p, sizeof p, "%s/%s", c->dir, h[i].name);
            if (!strcmp(p, keep)) continue;
            if (unlink(p) == 0) {
                total -= h[i].bytes;
                pthread_mutex_lock(&c->lock);
                c->stats.evicted++;
                pthread_mutex_unlock(&c->lock);
            }
        }
    }
    free(h);
}

void wf_plane_entry_close(wf_plane_entry *e)
{
    if (!e) return;
    if (!e->found && e->created) {
        int keep = !e->failed && e->nseen == e->nrows, err = 0;
        if (keep) {
            /* text, CRCs, then the blocks on the disk before the name: a crash leaves the old
             * name or a whole file, never a kept file with rows missing */
            char *hdr = calloc(1, TEXT);
            const char *key = strrchr(e->path, '/') + 1;
            char k[65];
            memcpy(k, key, 64);
            k[64] = '\0';
            err = hdr ? 0 : ENOMEM;
            if (!err) {
                header_text(e, k, hdr);
                err = write_all(e->fd, hdr, TEXT, 0);
            }
            free(hdr);
            if (!err) err = write_all(e->fd, e->crc, rows_kept(e) * sizeof *e->crc, TEXT);
            if (!err && fdatasync(e->fd) != 0) err = errno;
        }
        if (close(e->fd) != 0 && keep && !err) err = errno;
        e->fd = -1;
        if (keep && !err && rename(e->tmp, e->path) != 0) err = errno;
        if (keep && err) not_kept(e->c, "cannot keep", e->tmp, err);
        if (!keep || err) {
            unlink(e->tmp);
        } else {
            pthread_mutex_lock(&e->c->lock);
            e->c->stats.stored++;
            pthread_mutex_unlock(&e->c->lock);
            evict(e->c, e->path);
        }
    }
    if (e->fd >= 0) close(e->fd);
    pthread_mutex_destroy(&e->lock);
    free(e->seen);
    free(e->crc);
    free(e);
}
