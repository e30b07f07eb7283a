/* Firmware-path benchmark: one exposure of a sky-only scene through the readout, packets
 * to a null link (bytes counted, not kept), so that the time and peak RSS are those of the
 * firmware path alone.
 * usage: bench_readout NCOLS NROWS TILE_ROWS per-read|direct|moments|single MA_TABLE THREADS [raw]
 * `raw` turns deflate off, to separate the link's compression from the detector chain.
 * The checksum (sum of the packets' header CRC-32s, which cover the payload's CRC) does not
 * depend on the order threads send in, so two builds can be compared for identical output. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>

#include "hal/scene.h"
#include "tools/expose.h"

static size_t bytes_out;
static uint64_t checksum;
static wf_status null_send(void *ctx, const void *p, size_t len)
{
    (void)ctx;
    __atomic_fetch_add(&bytes_out, len, __ATOMIC_RELAXED);
    uint32_t crc;
    memcpy(&crc, (const unsigned char *)p + 44, sizeof crc);
    __atomic_fetch_add(&checksum, (uint64_t)crc, __ATOMIC_RELAXED);
    return WF_OK;
}

int main(int argc, char **argv)
{
    if (argc != 7 && !(argc == 8 && !strcmp(argv[7], "raw"))) {
        fprintf(stderr, "usage: %s NCOLS NROWS TILE_ROWS per-read|direct|moments|single MA_TABLE THREADS [raw]\n", argv[0]);
        return 2;
    }
    wf_expose_job job = {0};
    wf_readout_config *ro = &job.ro;
    ro->ncols = atoi(argv[1]);
    ro->nrows = atoi(argv[2]);
    ro->tile_rows = atoi(argv[3]);
    ro->mode = strcmp(argv[4], "single") ? WF_MODE_RAMP : WF_MODE_SINGLE;
    ro->sampling = !strcmp(argv[4], "direct")    ? WF_SAMPLE_DIRECT
                   : !strcmp(argv[4], "moments") ? WF_SAMPLE_MOMENTS
                                                 : WF_SAMPLE_PER_READ;
    ro->exptime = 300.0;
    ro->exposure = 1;
    ro->sca = 1;
    ro->seed = 1;
    ro->compress = argc == 7;
    wf_detector_defaults(&ro->det);
    job.clock.frame_time = WF_FRAME_TIME_DEFAULT;
    if (wf_ma_resolve(argv[5], &job.clock.ma)) { fprintf(stderr, "%s\n", wf_error_message()); return 1; }
    job.threads = atoi(argv[6]);
    job.noise = (wf_noise){WF_NOISE_PHILOX, 1, 1, 1};
    /* Y106 sky at the deep field, SPEC §2: 29.7 e-/s/arcsec^2 x 0.11^2 x 1.1 stray light */
    wf_scene_grid grid = {ro->ncols, ro->nrows, 29.7 * 0.11 * 0.11 * 1.1, 0.0, 1.0, 1 << 20};
    wf_scene_source src[8];
    for (int i = 0; i < 8; i++) wf_scene_grid_source(&grid, &src[i]);
    job.scenes = src;
    wf_link link = {NULL, null_send};
    job.link = &link;
    struct timespec a, b;
    clock_t c0 = clock();
    clock_gettime(CLOCK_MONOTONIC, &a);
    wf_status st = wf_expose_run(&job);
    clock_gettime(CLOCK_MONOTONIC, &b);
    double cpu = (double)(clock() - c0) / CLOCKS_PER_SEC;
    if (st) { fprintf(stderr, "bench: %s\n", wf_error_message()); return 1; }
    double wall = (b.tv_sec - a.tv_sec) + (b.tv_nsec - a.tv_nsec) * 1e-9;
    double reads = ro->mode == WF_MODE_RAMP
                       ? (ro->sampling != WF_SAMPLE_PER_READ ? job.clock.ma.nresultants : job.clock.ma.nreads)
                       : 1;
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double preads = (double)ro->ncols * ro->nrows * reads;
    printf("ncols=%d nrows=%d tile=%d mode=%s ma=%s threads=%d wall_s=%.3f cpu_s=%.3f "
           "pixel_reads=%.3g Mpixreads_per_cpu_s=%.2f arena_MiB=%.2f peak_rss_MiB=%.1f stream_MiB=%.1f checksum=%016llx\n",
           ro->ncols, ro->nrows, ro->tile_rows, argv[4], argv[5], job.threads, wall, cpu, preads,
           preads / cpu / 1e6, job.arena_bytes / 1048576.0, ru.ru_maxrss / 1024.0, bytes_out / 1048576.0,
           (unsigned long long)checksum);
    return 0;
}
