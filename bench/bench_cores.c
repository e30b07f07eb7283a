/* What a second core adds on this machine, per kind of work: the same task timed on one
 * thread alone and on two threads at once (each doing the whole task), so that
 * throughput = 2 x alone / at-once is 2 where the cores share nothing and less where they
 * contend. It tells a program's two-thread speed-up apart from what the machine allows:
 * arithmetic on data in the first-level cache, loads from working sets of growing size (private cache, shared
 * cache, memory), a memory stream, and the first touch of fresh pages.
 *
 *   bench_cores [rounds]
 *
 * One line per kind: the best time of the rounds alone and at once (the slower of the
 * two threads), and the throughput of two cores against one. The threads are not held on
 * cores, as wfisim's are not (on this kind of virtual machine, holding them made even the
 * arithmetic slower); each task runs long enough (~100 ms and more) that the scheduler's
 * first placement of the second thread does not count. */
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

typedef struct task {
    int kind;            /* 0 arithmetic, 1 loads, 2 stream, 3 fresh pages */
    size_t bytes;        /* working set */
    long reps;
    uint32_t *cycle;     /* loads: a random cycle through the working set */
    unsigned char *buf;  /* stream */
    pthread_barrier_t *start;
    double seconds;
    double sink;
} task;

/* 64 independent multiply-adds a step on an array the first-level cache holds: bound by the
 * core's own arithmetic and loads, not by latency nor by anything the cores share */
static double arithmetic(long reps)
{
    double a[64];
    for (int k = 0; k < 64; k++) a[k] = 1.0 + k * 1e-3;
    for (long i = 0; i < reps; i++)
        for (int k = 0; k < 64; k++) a[k] = a[k] * 0.9999999 + 1e-7;
    double s = 0;
    for (int k = 0; k < 64; k++) s += a[k];
    return s;
}

static double loads(const uint32_t *cycle, long reps)
{
    uint32_t x = 0;
    for (long i = 0; i < reps; i++) x = cycle[x];
    return x;
}

static double stream(unsigned char *buf, size_t bytes, long reps)
{
    for (long r = 0; r < reps; r++) memset(buf, (int)r, bytes);
    return buf[bytes / 2];
}

static double fresh_pages(size_t bytes)
{
    unsigned char *p = mmap(NULL, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return -1;
#ifdef MADV_NOHUGEPAGE
    (void)madvise(p, bytes, MADV_NOHUGEPAGE);
#endif
    for (size_t i = 0; i < bytes; i += 4096) p[i] = 1;
    double s = p[bytes / 2];
    munmap(p, bytes);
    return s;
}

static void *run(void *arg)
{
    task *t = arg;
    if (t->start) pthread_barrier_wait(t->start);
    double t0 = now();
    switch (t->kind) {
    case 0: t->sink = arithmetic(t->reps); break;
    case 1: t->sink = loads(t->cycle, t->reps); break;
    case 2: t->sink = stream(t->buf, t->bytes, t->reps); break;
    default: t->sink = fresh_pages(t->bytes); break;
    }
    t->seconds = now() - t0;
    return NULL;
}

/* Sattolo's shuffle: one cycle through every slot, so that each load depends on the last
 * and the hardware cannot guess the next address */
static uint32_t *make_cycle(size_t n, uint64_t seed)
{
    uint32_t *c = malloc(n * sizeof *c);
    if (!c) return NULL;
    for (size_t i = 0; i < n; i++) c[i] = (uint32_t)i;
    for (size_t i = n - 1; i > 0; i--) {
        seed ^= seed << 13, seed ^= seed >> 7, seed ^= seed << 17;
        size_t j = (size_t)(seed % i);
        uint32_t v = c[i];
        c[i] = c[j];
        c[j] = v;
    }
    return c;
}

static int prepare(task *t, int kind, size_t bytes, long reps, uint64_t seed)
{
    memset(t, 0, sizeof *t);
    t->kind = kind;
    t->bytes = bytes;
    t->reps = reps;
    if (kind == 1 && !(t->cycle = make_cycle(bytes / sizeof(uint32_t), seed))) return -1;
    if (kind == 2) {
        if (!(t->buf = malloc(bytes))) return -1;
        memset(t->buf, 1, bytes);
    }
    return 0;
}

int main(int argc, char **argv)
{
    const long rounds = argc > 1 ? atol(argv[1]) : 3;
    if (rounds < 1 || rounds > 100) {
        fprintf(stderr, "usage: bench_cores [rounds 1..100]\n");
        return 2;
    }
    static const struct { const char *name; int kind; size_t bytes; long reps; } cases[] = {
        {"arithmetic on 64 doubles (L1)", 0, 0, 12000000},
        {"dependent loads, 256 KiB", 1, 256 * 1024, 30000000},
        {"dependent loads, 2 MiB", 1, 2 * 1024 * 1024, 10000000},
        {"dependent loads, 8 MiB", 1, 8 * 1024 * 1024, 4000000},
        {"dependent loads, 64 MiB", 1, 64 * 1024 * 1024, 2000000},
        {"memory stream (memset), 64 MiB", 2, 64 * 1024 * 1024, 40},
        {"first touch of fresh 4 KiB pages, 64 MiB", 3, 64 * 1024 * 1024, 1},
    };
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        task t[2];
        if (prepare(&t[0], cases[c].kind, cases[c].bytes, cases[c].reps, 1) ||
            prepare(&t[1], cases[c].kind, cases[c].bytes, cases[c].reps, 2)) {
            fprintf(stderr, "bench_cores: out of memory\n");
            return 1;
        }
        double alone = 1e300, both = 1e300;
        for (long r = 0; r < rounds; r++) {
            run(&t[0]);
            if (t[0].seconds < alone) alone = t[0].seconds;
            pthread_barrier_t start;
            pthread_barrier_init(&start, NULL, 2);
            t[0].start = t[1].start = &start;
            pthread_t th;
            if (pthread_create(&th, NULL, run, &t[1]) != 0) {
                fprintf(stderr, "bench_cores: cannot start a thread\n");
                return 1;
            }
            run(&t[0]);
            pthread_join(th, NULL);
            pthread_barrier_destroy(&start);
            t[0].start = t[1].start = NULL;
            double slower = t[0].seconds > t[1].seconds ? t[0].seconds : t[1].seconds;
            if (slower < both) both = slower;
        }
        if (t[0].sink < 0 || t[1].sink < 0) {
            fprintf(stderr, "bench_cores: cannot map fresh memory\n");
            return 1;
        }
        printf("case=\"%s\" alone_ms=%.2f both_ms=%.2f throughput_x=%.2f\n", cases[c].name, alone * 1e3,
               both * 1e3, 2 * alone / both);
        free(t[0].cycle);
        free(t[1].cycle);
        free(t[0].buf);
        free(t[1].buf);
    }
    return 0;
}
