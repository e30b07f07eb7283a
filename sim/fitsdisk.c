#include "sim/fitsdisk.h"

#include "hal/arena.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <fitsio2.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define PREFIX "wfdisk://"
#define NSLOTS 1024 /* files being created at once; a slot costs its buffer only when used */
#define BUF_BYTES ((size_t)1 << 20)
/* A write this large goes to the file as it is: the buffer gathers cfitsio's 2880-byte
 * records into large writes, and copying an already large one into it gains nothing */
#define DIRECT_BYTES ((size_t)1 << 18)

typedef struct hole { long long lo, hi; } hole;

/* One open file. cfitsio calls a handle's read/write/seek from the one thread that owns the
 * fitsfile, so only taking and freeing a slot needs the lock. */
typedef struct slot {
    int used, fd, dirty;        /* dirty: buf holds bytes not yet written */
    int creating;               /* inside wf_fitsdisk_create: a close leaves the slot to it */
    int created;                /* the file on disk is this slot's own */
    int error;                  /* the first failed write: cfitsio ignores a flush's status,
                                 * so every later call, the close included, returns it */
    char *path;
    long long pos;              /* cfitsio's position */
    long long size;             /* the file as cfitsio sees it: on disk, buffered, holes */
    long long disk;             /* bytes on disk (what fstat would say) */
    unsigned char *buf;         /* write-back buffer, or a clean read cache */
    long long buf_off;
    size_t buf_len;
    long long read_end;         /* where the last read stopped: the next one there is sequential */
    hole *holes;                /* ranges never written (zeros), sorted, disjoint */
    size_t nholes, holes_cap;
} slot;

static slot slots[NSLOTS];
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_once_t once = PTHREAD_ONCE_INIT;
static int registered_status;

static slot *slot_of(int handle)
{
    return handle >= 0 && handle < NSLOTS && slots[handle].used ? &slots[handle] : NULL;
}

/* cfitsio's error stack gets the system's reason: a write that fails at a later flush
 * would otherwise be reported as whatever cfitsio was doing then (often a read). */
static int sys_error(int code, const char *doing)
{
    char msg[FLEN_ERRMSG];
    snprintf(msg, sizeof msg, "wfisim disk driver: %s: %s", doing, strerror(errno ? errno : EIO));
    ffpmsg(msg);
    return code;
}

static int pwrite_all(slot *s, const unsigned char *p, size_t n, long long off)
{
    while (n) {
        ssize_t w = pwrite(s->fd, p, n, (off_t)off);
        if (w < 0 && errno == EINTR) continue;
        if (w == 0) errno = EIO;
        if (w <= 0) return s->error = sys_error(WRITE_ERROR, "write failed"); /* a full disk included */
        p += w;
        n -= (size_t)w;
        off += w;
    }
    if (off > s->disk) s->disk = off;
    return 0;
}

/* Reads [off, off + n) of the file as cfitsio sees it: bytes past the end on disk but
 * inside the size are a hole not yet extended, so zeros. */
static int pread_all(slot *s, unsigned char *p, size_t n, long long off)
{
    if (off + (long long)n > s->size) return READ_ERROR;
    while (n && off < s->disk) {
        ssize_t r = pread(s->fd, p, n, (off_t)off);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) return sys_error(READ_ERROR, "read failed");
        if (r == 0) break;
        p += r;
        n -= (size_t)r;
        off += r;
    }
    memset(p, 0, n);
    return 0;
}

static int flush_buf(slot *s)
{
    if (s->error) return s->error;
    int st = 0;
    if (s->dirty && s->buf_len) st = pwrite_all(s, s->buf, s->buf_len, s->buf_off);
    s->dirty = 0;
    s->buf_len = 0;
    return st;
}

/* Everything cfitsio wrote is on disk, holes included, so that another reader of the path
 * (the header checksum, a verifier) sees the file cfitsio sees. */
static int sync_disk(slot *s)
{
    int st = flush_buf(s);
    if (!st && s->size > s->disk) {
        if (ftruncate(s->fd, (off_t)s->size) != 0)
            return s->error = sys_error(WRITE_ERROR, "extending the file failed");
        s->disk = s->size;
    }
    return st;
}

/* The holes: zero records cfitsio appended and the driver did not write. cfitsio reads a
 * record back before it writes part of it (the first and last records of every run of rows),
 * and one inside a hole is zeros without asking the kernel, or flushing the buffer first. */
static int hole_covers(const slot *s, long long lo, long long hi)
{
    for (size_t i = 0; i < s->nholes; i++)
        if (s->holes[i].lo <= lo) {
            if (hi <= s->holes[i].hi) return 1;
        } else {
            break;
        }
    return 0;
}

/* Room for one more hole; nonzero when out of memory. */
static int holes_room(slot *s)
{
    if (s->nholes < s->holes_cap) return 0;
    size_t cap = s->holes_cap ? 2 * s->holes_cap : 16;
    hole *v = realloc(s->holes, cap * sizeof *v);
    if (!v) return 1;
    s->holes = v;
    s->holes_cap = cap;
    return 0;
}

/* [lo, hi) now holds written bytes: no longer (part of) a hole. */
static int hole_fill(slot *s, long long lo, long long hi)
{
    for (size_t i = 0; i < s->nholes; i++) {
        hole *h = &s->holes[i];
        if (h->hi <= lo) continue;
        if (h->lo >= hi) break;
        if (h->lo < lo && h->hi > hi) { /* split in two */
            if (holes_room(s)) return MEMORY_ALLOCATION;
            h = &s->holes[i];
            memmove(h + 1, h, (s->nholes - i) * sizeof *h);
            s->nholes++;
            h[0].hi = lo;
            h[1].lo = hi;
            return 0;
        }
        if (h->lo >= lo && h->hi <= hi) { /* gone */
            memmove(h, h + 1, (s->nholes - i - 1) * sizeof *h);
            s->nholes--;
            i--;
        } else if (h->lo < lo) {
            h->hi = lo;
        } else {
            h->lo = hi;
        }
    }
    return 0;
}

/* Zeros appended at the end of the file: a new hole, or the last one grown. */
static int hole_append(slot *s, long long lo, long long hi)
{
    if (s->nholes && s->holes[s->nholes - 1].hi == lo) {
        s->holes[s->nholes - 1].hi = hi;
        return 0;
    }
    if (holes_room(s)) return MEMORY_ALLOCATION;
    s->holes[s->nholes++] = (hole){lo, hi};
    return 0;
}

static int all_zero(const unsigned char *p, size_t n)
{
    uint64_t acc = 0, w;
    size_t i = 0;
    for (; i + 8 <= n; i += 8) {
        memcpy(&w, p + i, 8);
        acc |= w;
        if (acc) return 0;
    }
    for (; i < n; i++) acc |= p[i];
    return acc == 0;
}

static int d_init(void) { return 0; }
static int d_shutdown(void) { return 0; }
static int d_setoptions(int options) { (void)options; return 0; }
static int d_getoptions(int *options) { *options = 0; return 0; }
static int d_getversion(int *version) { *version = 1; return 0; }
static int d_checkfile(char *urltype, char *infile, char *outfile)
{
    (void)urltype; (void)infile; (void)outfile;
    return 0;
}

/* Only wf_fitsdisk_create makes these files; reopening goes through file://. */
static int d_open(char *filename, int rwmode, int *handle)
{
    (void)filename; (void)rwmode; (void)handle;
    return FILE_NOT_OPENED;
}

/* filename is the slot number wf_fitsdisk_create passed, so that no character of the real
 * path reaches cfitsio's filename parser. */
static int d_create(char *filename, int *handle)
{
    char *end = NULL;
    long i = strtol(filename, &end, 10);
    slot *s = end != filename && !*end ? slot_of((int)i) : NULL;
    if (!s || s->fd >= 0) return FILE_NOT_CREATED;
    s->fd = open(s->path, O_RDWR | O_CREAT | O_EXCL, 0666);
    if (s->fd < 0) return FILE_NOT_CREATED;
    s->created = 1;
    *handle = (int)i;
    return 0;
}

static int d_truncate(int handle, LONGLONG size)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    int st = flush_buf(s);
    if (st) return st;
    if (ftruncate(s->fd, (off_t)size) != 0) return s->error = sys_error(WRITE_ERROR, "truncating the file failed");
    if ((st = hole_fill(s, size, LLONG_MAX))) return st; /* what was cut off is no hole */
    s->size = s->disk = size;
    s->pos = size; /* as file:// does: cfitsio takes the end of the file for its position */
    return 0;
}

static void slot_free(slot *s)
{
    pthread_mutex_lock(&lock);
    free(s->buf);
    free(s->path);
    free(s->holes);
    memset(s, 0, sizeof *s);
    s->fd = -1;
    pthread_mutex_unlock(&lock);
}

static int d_close(int handle)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    int st = sync_disk(s);
    if (close(s->fd) != 0 && !st) st = sys_error(FILE_NOT_CLOSED, "close failed");
    s->fd = -1;
    if (!s->creating) slot_free(s);
    return st;
}

/* fits_delete_file closes (freeing the slot) before it removes, so the slot number no
 * longer names this file, and may name another thread's: refused. Products are removed by
 * their path (wf_fits_finish). */
static int d_remove(char *filename)
{
    (void)filename;
    return FILE_NOT_OPENED;
}

static int d_size(int handle, LONGLONG *size)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    *size = s->size;
    return 0;
}

static int d_flush(int handle)
{
    slot *s = slot_of(handle);
    return s ? sync_disk(s) : BAD_FILEPTR;
}

static int d_seek(int handle, LONGLONG offset)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    s->pos = offset;
    return 0;
}

static int d_read(int handle, void *buffer, long nbytes)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    size_t n = (size_t)nbytes;
    int st = 0;
    if (s->error) return s->error;
    if (s->pos + (long long)n <= s->size && hole_covers(s, s->pos, s->pos + (long long)n)) {
        memset(buffer, 0, n); /* never written, so not in the buffer either */
        s->pos += (long long)n;
        s->read_end = s->pos;
        return 0;
    }
    if (s->dirty && (st = flush_buf(s))) return st;
    if (s->buf_len && s->pos >= s->buf_off && s->pos + (long long)n <= s->buf_off + (long long)s->buf_len) {
        memcpy(buffer, s->buf + (s->pos - s->buf_off), n);
    } else if (n >= BUF_BYTES || s->pos != s->read_end) {
        /* a lone record (cfitsio loading one to change part of it) is read as it is: a
         * megabyte around it would be thrown away by the write that follows */
        s->buf_len = 0;
        if ((st = pread_all(s, buffer, n, s->pos))) return st;
    } else {
        if (s->pos + (long long)n > s->size) return READ_ERROR;
        long long len = s->size - s->pos;
        size_t fill = len < (long long)BUF_BYTES ? (size_t)len : BUF_BYTES;
        s->buf_len = 0;
        if ((st = pread_all(s, s->buf, fill, s->pos))) return st;
        s->buf_off = s->pos;
        s->buf_len = fill;
        memcpy(buffer, s->buf, n);
    }
    s->pos += (long long)n;
    s->read_end = s->pos;
    return 0;
}

static int d_write(int handle, void *buffer, long nbytes)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    const unsigned char *p = buffer;
    size_t n = (size_t)nbytes;
    int st = 0;
    if (s->error) return s->error;
    long long end = s->pos + (long long)n;
    if ((s->pos >= s->size || hole_covers(s, s->pos, end)) && all_zero(p, n)) {
        /* cfitsio's fill records: a hole reads back the same zeros */
        if (s->pos >= s->size && (st = hole_append(s, s->size, end))) return st;
        s->pos = end;
        if (s->pos > s->size) s->size = s->pos;
        return 0;
    }
    if ((st = hole_fill(s, s->pos, end))) return st;
    if (n < DIRECT_BYTES && s->dirty && s->pos == s->buf_off + (long long)s->buf_len &&
        s->buf_len + n <= BUF_BYTES) {
        memcpy(s->buf + s->buf_len, p, n);
        s->buf_len += n;
    } else {
        if ((st = flush_buf(s))) return st; /* also drops a read cache the write may overlap */
        if (n >= DIRECT_BYTES) {
            if ((st = pwrite_all(s, p, n, s->pos))) return st;
        } else {
            memcpy(s->buf, p, n);
            s->buf_off = s->pos;
            s->buf_len = n;
            s->dirty = 1;
        }
    }
    s->pos += (long long)n;
    if (s->pos > s->size) s->size = s->pos;
    return 0;
}

static void register_driver(void)
{
    /* cfitsio registers its own drivers on first use; ours must come after, or the
     * initialisation would start the table afresh */
    fits_init_cfitsio();
    for (int i = 0; i < NSLOTS; i++) slots[i].fd = -1;
    registered_status = fits_register_driver(PREFIX, d_init, d_shutdown, d_setoptions, d_getoptions,
                                             d_getversion, d_checkfile, d_open, d_create, d_truncate,
                                             d_close, d_remove, d_size, d_flush, d_seek, d_read, d_write);
}

int wf_fitsdisk_create(fitsfile **f, const char *path, int *status)
{
    *f = NULL;
    if (*status > 0) return *status;
    pthread_once(&once, register_driver);
    if (registered_status) return *status = registered_status;
    int i;
    unsigned char *buf = wf_arena_host_realloc(NULL, 0, BUF_BYTES);
    char *copy = strdup(path);
    pthread_mutex_lock(&lock);
    for (i = 0; i < NSLOTS && slots[i].used; i++) {}
    if (i < NSLOTS && buf && copy) {
        slots[i].used = 1;
        slots[i].creating = 1;
        slots[i].path = copy;
        slots[i].buf = buf;
    }
    pthread_mutex_unlock(&lock);
    if (i == NSLOTS || !buf || !copy) {
        free(buf);
        free(copy);
        return *status = i == NSLOTS ? TOO_MANY_FILES : MEMORY_ALLOCATION;
    }
    char name[32];
    snprintf(name, sizeof name, PREFIX "%d", i);
    /* the slot stays this call's until it returns, even if cfitsio closes it on a failure */
    if (fits_create_file(f, name, status)) {
        *f = NULL;
        if (slots[i].fd >= 0) close(slots[i].fd);
        if (slots[i].created) unlink(slots[i].path); /* ours: leave nothing behind */
        slot_free(&slots[i]);
    } else {
        slots[i].creating = 0;
    }
    return *status;
}
