/* What the first touch of fresh memory costs, in ordinary 4 KiB pages and in the huge pages
 * of wf_arena_host_realloc (hal/arena.h): the reason the host's large buffers take them. On a
 * virtual machine each page fault also exits to the hypervisor, so a 4 KiB fault can cost as
 * much as filling its page many times over.
 *
 *   bench_pages [MiB] [rounds]
 *
 * Prints one line per kind: the first fill (page faults and their zeroing included) and a
 * second fill of the same memory (the fill alone), in ms per MiB, best of the rounds. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <time.h>

#include "hal/arena.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static long faults(void)
{
    struct rusage r;
    getrusage(RUSAGE_SELF, &r);
    return r.ru_minflt;
}

int main(int argc, char **argv)
{
    const size_t mib = (size_t)1 << 20;
    const long n_mib = argc > 1 ? atol(argv[1]) : 64, rounds = argc > 2 ? atol(argv[2]) : 3;
    if (n_mib < 1 || n_mib > 4096 || rounds < 1) {
        fprintf(stderr, "usage: bench_pages [MiB 1..4096] [rounds >= 1]\n");
        return 2;
    }
    const size_t n = (size_t)n_mib * mib;
    for (int huge = 0; huge < 2; huge++) {
        double best1 = 1e300, best2 = 1e300;
        long nf = 0;
        for (long r = 0; r < rounds; r++) {
            unsigned char *p;
            if (huge) {
                p = wf_arena_host_realloc(NULL, 0, n);
            } else {
                p = malloc(n); /* above malloc's mmap threshold: fresh pages from the kernel */
                if (p) (void)madvise((void *)((uintptr_t)p & ~(uintptr_t)4095), n, MADV_NOHUGEPAGE);
            }
            if (!p) {
                fprintf(stderr, "bench_pages: cannot allocate %ld MiB\n", n_mib);
                return 1;
            }
            long f0 = faults();
            double t0 = now();
            memset(p, 1, n);
            double t1 = now();
            memset(p, 2, n);
            double t2 = now();
            nf = faults() - f0;
            if (t1 - t0 < best1) best1 = t1 - t0;
            if (t2 - t1 < best2) best2 = t2 - t1;
            free(p);
        }
        printf("pages=%s MiB=%ld first_touch_ms_per_MiB=%.3f refill_ms_per_MiB=%.3f faults=%ld "
               "us_per_fault=%.2f\n", huge ? "huge" : "4KiB", n_mib, 1e3 * best1 / n_mib,
               1e3 * best2 / n_mib, nf, nf ? 1e6 * (best1 - best2) / nf : 0.0);
    }
    return 0;
}
