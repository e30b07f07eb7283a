#define _GNU_SOURCE /* O_DIRECT, statx */
#include "sim/fits/fitsdisk.h"

#include "hal/arena.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <fitsio2.h>
#include <pthread.h>
#include <stdatomic.h>
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
/* The first read ahead of a sequential run is the length of the last run (at least
 * AHEAD_MIN), doubled at each refill up to BUF_BYTES: cfitsio reads a tile of resultants
 * back one plane's rows at a time, runs of one length (128 KiB for 1024 columns and 64 rows),
 * and a megabyte each time read eight times what was used */
#define AHEAD_MIN ((size_t)1 << 15)
/* Writes bypass the page cache (O_DIRECT) where the file system takes
 * it: copying 200 MB into the page cache, on pages the kernel must first fault in and
 * zero, cost a single-frame product 0.05-0.45 CPU-s (the spread is the host's), the
 * device's own transfer ~0.03 s. The bytes go through an aligned bounce buffer, since
 * cfitsio's records (2880 bytes) leave rows at no particular alignment. */
#define FRAGS_MAX 512 /* pages waiting: past it they all go through the page cache */
#define BOUNCE_BYTES ((size_t)1 << 22)

typedef struct hole { long long lo, hi; } hole;

/* Part of one aligned page written by an uncached write and not yet on disk: a page goes
 * out uncached only whole, so the edges of each write wait here for their neighbours (the
 * next tile's rows, usually). What is left at a flush, a read or a cached write over it
 * goes through the page cache. */
typedef struct frag {
    long long page;
    size_t lo, hi;
    unsigned char *data; /* the page's bytes; only [lo, hi) mean anything */
} frag;

/* One open file. cfitsio calls a handle's read/write/seek from the one thread that owns the
 * fitsfile, so only taking and freeing a slot needs the lock. */
typedef struct slot {
    int used, fd, dirty;        /* dirty: buf holds bytes not yet written */
    int ufd;                    /* the same file opened O_DIRECT, or -1 */
    int try_uncached;           /* wf_fitsdisk_uncached when the slot was taken */
    size_t align;               /* ufd's offset and length unit: a multiple of the page */
    int creating;               /* inside wf_fitsdisk_create: a close leaves the slot to it */
    int created;                /* the file on disk is this slot's own */
    int error;                  /* the first failed write: cfitsio ignores a flush's status,
                                 * so every later call, the close included, returns it */
    char *path;
    long long pos;              /* cfitsio's position */
    long long size;             /* the file as cfitsio sees it: on disk, buffered, holes */
    long long disk;             /* bytes on disk (what fstat would say) */
    unsigned char *buf;         /* write-back buffer */
    long long buf_off;
    size_t buf_len;
    /* Read cache, apart from the write-back buffer so that a write elsewhere keeps it: cfitsio
     * reading a run of records back (a tile of resultants) writes out its own dirty records
     * between them, and a shared buffer was refilled, 1 MiB, at every record. Every write
     * over it is copied into it too, so it always holds the file's latest bytes. */
    unsigned char *rbuf;
    long long rbuf_off;
    size_t rbuf_len;
    size_t ahead;               /* the next read ahead; 0 until the first */
    long long run_start;        /* where the current sequential run of reads began */
    long long read_end;         /* where the last read stopped: the next one there is sequential */
    hole *holes;                /* ranges never written (zeros), sorted, disjoint */
    size_t nholes, holes_cap;
    unsigned char *bounce;      /* BOUNCE_BYTES aligned for ufd */
    frag *frags;
    size_t nfrags, frags_cap;
} slot;

static slot slots[NSLOTS];
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_once_t once = PTHREAD_ONCE_INIT;
static int registered_status;
static int uncached_off; /* wf_fitsdisk_uncached(0) */
static atomic_llong bytes_uncached, bytes_cached, bytes_read;

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

/* fd: s->fd, or s->ufd (the bytes aligned for it); -1 when that was closed meanwhile. */
static int write_fd(slot *s, int fd, const unsigned char *p, size_t n, long long off)
{
    if (fd < 0) fd = s->fd;
    while (n) {
        ssize_t w = pwrite(fd, p, n, (off_t)off);
        if (w < 0 && errno == EINTR) continue;
        if (w < 0 && errno == EINVAL && fd == s->ufd && s->fd >= 0) {
            /* the file system refuses uncached writes after all: the page cache from here */
            close(s->ufd);
            s->ufd = -1;
            fd = s->fd;
            continue;
        }
        if (w == 0) errno = EIO;
        if (w <= 0) return s->error = sys_error(WRITE_ERROR, "write failed"); /* a full disk included */
        atomic_fetch_add(fd == s->ufd ? &bytes_uncached : &bytes_cached, (long long)w);
        if (fd == s->ufd && (size_t)w % s->align) fd = s->fd; /* short: the rest is unaligned */
        p += w;
        n -= (size_t)w;
        off += w;
    }
    if (off > s->disk) s->disk = off;
    return 0;
}

/* Fragments of pages in [lo, hi) go to the file through the page cache, oldest bytes
 * first, so that a cached write or a read of that range sees the latest. */
static int frags_flush(slot *s, long long lo, long long hi)
{
    size_t keep = 0;
    int st = 0;
    for (size_t i = 0; i < s->nfrags; i++) {
        frag *g = &s->frags[i];
        long long at = g->page * (long long)s->align;
        if (!st && at + (long long)g->hi > lo && at + (long long)g->lo < hi) {
            st = write_fd(s, s->fd, g->data + g->lo, g->hi - g->lo, at + (long long)g->lo);
            free(g->data);
        } else {
            s->frags[keep++] = *g;
        }
    }
    s->nfrags = keep;
    return st;
}

/* Adds [lo, hi) of a page (bytes p) to its fragment. *whole is set when the page is now
 * complete: its bytes are then in *data, the fragment's, for the caller to write and free. */
static int frag_add(slot *s, long long page, size_t lo, size_t hi, const unsigned char *p,
                    unsigned char **whole)
{
    *whole = NULL;
    frag *g = NULL;
    for (size_t i = 0; i < s->nfrags && !g; i++)
        if (s->frags[i].page == page) g = &s->frags[i];
    if (g && (hi < g->lo || lo > g->hi)) {
        /* a gap between them: the old part goes out now (rare: a write left out of order) */
        long long at = page * (long long)s->align;
        int st = write_fd(s, s->fd, g->data + g->lo, g->hi - g->lo, at + (long long)g->lo);
        if (st) return st;
        g->lo = lo;
        g->hi = hi;
    }
    if (!g) {
        if (s->nfrags == s->frags_cap) {
            size_t cap = s->frags_cap ? 2 * s->frags_cap : 8;
            frag *v = realloc(s->frags, cap * sizeof *v);
            if (!v) return MEMORY_ALLOCATION;
            s->frags = v;
            s->frags_cap = cap;
        }
        unsigned char *d = malloc(s->align);
        if (!d) return MEMORY_ALLOCATION;
        g = &s->frags[s->nfrags++];
        *g = (frag){page, lo, hi, d};
    }
    memcpy(g->data + lo, p, hi - lo); /* the newer bytes win where they overlap */
    if (lo < g->lo) g->lo = lo;
    if (hi > g->hi) g->hi = hi;
    if (g->lo == 0 && g->hi == s->align) {
        *whole = g->data;
        *g = s->frags[--s->nfrags];
    }
    return 0;
}

/* [off, off + n) of the file: bytes, then a whole page before and after (either may be
 * NULL), through the bounce buffer to the uncached descriptor. */
static int write_uncached(slot *s, const unsigned char *head, const unsigned char *p, size_t n,
                          const unsigned char *tail, long long off)
{
    const size_t a = s->align;
    const unsigned char *part[3] = {head, p, tail};
    size_t len[3] = {head ? a : 0, n, tail ? a : 0};
    size_t fill = 0;
    for (int k = 0; k < 3; k++) {
        const unsigned char *q = part[k];
        size_t left = len[k];
        while (left) {
            size_t take = BOUNCE_BYTES - fill < left ? BOUNCE_BYTES - fill : left;
            memcpy(s->bounce + fill, q, take);
            fill += take;
            q += take;
            left -= take;
            if (fill == BOUNCE_BYTES) {
                int st = write_fd(s, s->ufd, s->bounce, fill, off);
                if (st) return st;
                off += (long long)fill;
                fill = 0;
            }
        }
    }
    return fill ? write_fd(s, s->ufd, s->bounce, fill, off) : 0;
}

/* Every write of bytes to the file. With the uncached descriptor, the whole pages of the
 * range go out at once and its partial first and last pages wait as fragments. */
static int write_out(slot *s, const unsigned char *p, size_t n, long long off)
{
    if (s->ufd < 0) {
        int st = s->nfrags ? frags_flush(s, off, off + (long long)n) : 0;
        return st ? st : write_fd(s, s->fd, p, n, off);
    }
    if (!n) return 0;
    const long long a = (long long)s->align, end = off + (long long)n;
    unsigned char *head = NULL, *tail = NULL;
    int st = 0;
    if (s->nfrags >= FRAGS_MAX && (st = frags_flush(s, 0, LLONG_MAX))) return st;
    if (off / a == (end - 1) / a && off % a && end % a) { /* inside one page */
        long long page = off / a;
        st = frag_add(s, page, (size_t)(off - page * a), (size_t)(end - page * a), p, &head);
        if (!st && head) st = write_uncached(s, head, NULL, 0, NULL, page * a);
        free(head);
        return st;
    }
    long long first = (off + a - 1) / a, last = end / a; /* whole pages [first, last) */
    size_t keep = 0; /* what waited for the pages written whole is older */
    for (size_t i = 0; i < s->nfrags; i++) {
        if (s->frags[i].page >= first && s->frags[i].page < last) free(s->frags[i].data);
        else s->frags[keep++] = s->frags[i];
    }
    s->nfrags = keep;
    size_t pre = (size_t)(first * a - off), post = (size_t)(end - last * a);
    if (pre) st = frag_add(s, first - 1, (size_t)(a - (long long)pre), (size_t)a, p, &head);
    if (!st && post) st = frag_add(s, last, 0, post, p + (n - post), &tail);
    if (!st)
        st = write_uncached(s, head, p + pre, n - pre - post, tail,
                            head ? (first - 1) * a : first * a);
    free(head);
    free(tail);
    return st;
}

/* Reads [off, off + n) of the file as cfitsio sees it: bytes past the end on disk but
 * inside the size are a hole not yet extended, so zeros. */
static int pread_all(slot *s, unsigned char *p, size_t n, long long off)
{
    if (off + (long long)n > s->size) return READ_ERROR;
    int st = s->nfrags ? frags_flush(s, off, off + (long long)n) : 0;
    if (st) return st;
    while (n && off < s->disk) {
        ssize_t r = pread(s->fd, p, n, (off_t)off);
        if (r < 0 && errno == EINTR) continue;
        if (r < 0) return sys_error(READ_ERROR, "read failed");
        if (r == 0) break;
        atomic_fetch_add(&bytes_read, (long long)r);
        p += r;
        n -= (size_t)r;
        off += r;
    }
    memset(p, 0, n);
    return 0;
}

/* Copies what [src_off, src_off + src_len) has of [dst_off, dst_off + dst_len) into dst. */
static void copy_overlap(unsigned char *dst, long long dst_off, size_t dst_len, const unsigned char *src,
                         long long src_off, size_t src_len)
{
    long long lo = dst_off > src_off ? dst_off : src_off;
    long long hi = dst_off + (long long)dst_len, shi = src_off + (long long)src_len;
    if (shi < hi) hi = shi;
    if (lo < hi) memcpy(dst + (lo - dst_off), src + (lo - src_off), (size_t)(hi - lo));
}

static int overlaps(long long a, size_t an, long long b, size_t bn)
{
    return an && bn && a < b + (long long)bn && b < a + (long long)an;
}

static int flush_buf(slot *s)
{
    if (s->error) return s->error;
    int st = 0;
    if (s->dirty && s->buf_len) st = write_out(s, s->buf, s->buf_len, s->buf_off);
    s->dirty = 0;
    s->buf_len = 0;
    return st;
}

/* Everything cfitsio wrote is on disk, holes included, so that another reader of the path
 * (the header checksum, a verifier) sees the file cfitsio sees. */
static int sync_disk(slot *s)
{
    int st = flush_buf(s);
    if (!st && s->nfrags) st = frags_flush(s, 0, LLONG_MAX);
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

/* A second descriptor of the new file without the page cache, where the file system
 * states its alignment for it (statx; tmpfs, for one, does not) and it is a divisor of a
 * page; reopened through /proc so that it is this file whatever happens to the path. */
static void open_uncached(slot *s)
{
#ifdef STATX_DIOALIGN
    struct statx sx;
    long page = sysconf(_SC_PAGESIZE);
    if (!s->try_uncached || page <= 0 || statx(s->fd, "", AT_EMPTY_PATH, STATX_DIOALIGN, &sx) != 0 ||
        !(sx.stx_mask & STATX_DIOALIGN) || !sx.stx_dio_offset_align || !sx.stx_dio_mem_align ||
        page % sx.stx_dio_offset_align || page % sx.stx_dio_mem_align)
        return;
    char name[64];
    snprintf(name, sizeof name, "/proc/self/fd/%d", s->fd);
    void *b = NULL;
    if (posix_memalign(&b, (size_t)page, BOUNCE_BYTES) != 0) return;
    s->ufd = open(name, O_WRONLY | O_DIRECT);
    if (s->ufd < 0) {
        free(b);
        return;
    }
    s->bounce = b;
    s->align = (size_t)page;
#else
    (void)s;
#endif
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
    open_uncached(s);
    *handle = (int)i;
    return 0;
}

static int d_truncate(int handle, LONGLONG size)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    int st = flush_buf(s);
    if (!st && s->nfrags) st = frags_flush(s, 0, LLONG_MAX);
    if (st) return st;
    if (ftruncate(s->fd, (off_t)size) != 0) return s->error = sys_error(WRITE_ERROR, "truncating the file failed");
    s->rbuf_len = 0;
    if ((st = hole_fill(s, size, LLONG_MAX))) return st; /* what was cut off is no hole */
    s->size = s->disk = size;
    s->pos = size; /* as file:// does: cfitsio takes the end of the file for its position */
    return 0;
}

static void slot_free(slot *s)
{
    pthread_mutex_lock(&lock);
    free(s->buf);
    free(s->rbuf);
    free(s->path);
    free(s->holes);
    for (size_t i = 0; i < s->nfrags; i++) free(s->frags[i].data);
    free(s->frags);
    free(s->bounce);
    if (s->ufd >= 0) close(s->ufd);
    memset(s, 0, sizeof *s);
    s->fd = s->ufd = -1;
    pthread_mutex_unlock(&lock);
}

static int d_close(int handle)
{
    slot *s = slot_of(handle);
    if (!s) return BAD_FILEPTR;
    int st = sync_disk(s);
    if (close(s->fd) != 0 && !st) st = sys_error(FILE_NOT_CLOSED, "close failed");
    if (s->ufd >= 0 && close(s->ufd) != 0 && !st) st = sys_error(FILE_NOT_CLOSED, "close failed");
    s->fd = s->ufd = -1;
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
        s->read_end = s->run_start = s->pos; /* zeros are no part of a run read from the file */
        return 0;
    }
    const long long lo = s->pos;
    const int in_buf = s->dirty && overlaps(lo, n, s->buf_off, s->buf_len);
    if (in_buf && lo >= s->buf_off && lo + (long long)n <= s->buf_off + (long long)s->buf_len) {
        memcpy(buffer, s->buf + (lo - s->buf_off), n); /* cfitsio reloading what it just wrote */
    } else if (s->rbuf_len && lo >= s->rbuf_off && lo + (long long)n <= s->rbuf_off + (long long)s->rbuf_len) {
        memcpy(buffer, s->rbuf + (lo - s->rbuf_off), n);
    } else if (n >= BUF_BYTES || lo != s->read_end) {
        /* a lone record (cfitsio loading one to change part of it) is read as it is: a
         * megabyte around it would be thrown away by the write that follows */
        long long run = s->read_end - s->run_start;
        s->ahead = run < (long long)AHEAD_MIN ? AHEAD_MIN : run > (long long)BUF_BYTES ? BUF_BYTES : (size_t)run;
        s->run_start = lo;
        if (in_buf && (st = flush_buf(s))) return st;
        if ((st = pread_all(s, buffer, n, lo))) return st;
    } else {
        if (lo + (long long)n > s->size) return READ_ERROR;
        if (!s->rbuf && !(s->rbuf = malloc(BUF_BYTES))) return MEMORY_ALLOCATION;
        long long len = s->size - lo;
        size_t want = s->ahead ? s->ahead : AHEAD_MIN;
        if (want < n) want = n;
        size_t fill = len < (long long)want ? (size_t)len : want;
        s->ahead = 2 * want < BUF_BYTES ? 2 * want : BUF_BYTES;
        s->rbuf_len = 0;
        if ((st = pread_all(s, s->rbuf, fill, lo))) return st;
        /* bytes still in the write-back buffer are newer than the file's */
        if (s->dirty) copy_overlap(s->rbuf, lo, fill, s->buf, s->buf_off, s->buf_len);
        s->rbuf_off = lo;
        s->rbuf_len = fill;
        memcpy(buffer, s->rbuf, n);
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
    if (overlaps(s->pos, n, s->rbuf_off, s->rbuf_len))
        copy_overlap(s->rbuf, s->rbuf_off, s->rbuf_len, p, s->pos, n);
    if (n < DIRECT_BYTES && s->dirty && s->pos == s->buf_off + (long long)s->buf_len &&
        s->buf_len + n <= BUF_BYTES) {
        memcpy(s->buf + s->buf_len, p, n);
        s->buf_len += n;
    } else {
        if ((st = flush_buf(s))) return st;
        if (n >= DIRECT_BYTES) {
            if ((st = write_out(s, p, n, s->pos))) return st;
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
    for (int i = 0; i < NSLOTS; i++) slots[i].fd = slots[i].ufd = -1;
    registered_status = fits_register_driver(PREFIX, d_init, d_shutdown, d_setoptions, d_getoptions,
                                             d_getversion, d_checkfile, d_open, d_create, d_truncate,
                                             d_close, d_remove, d_size, d_flush, d_seek, d_read, d_write);
}

void wf_fitsdisk_uncached(int enabled)
{
    pthread_mutex_lock(&lock);
    uncached_off = !enabled;
    pthread_mutex_unlock(&lock);
}

void wf_fitsdisk_written(long long *uncached, long long *cached)
{
    *uncached = atomic_load(&bytes_uncached);
    *cached = atomic_load(&bytes_cached);
}

long long wf_fitsdisk_read_back(void)
{
    return atomic_load(&bytes_read);
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
        slots[i].try_uncached = !uncached_off;
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
