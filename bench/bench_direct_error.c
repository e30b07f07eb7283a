/* Error of direct-resultant sampling against per-read sampling, the high-fidelity
 * reference: flat fields at several rates through the whole chain (readout, assembly with
 * linearity correction, ramp fit), with nonlinearity on and off. Reports the mean fitted
 * rate of each mode, their relative difference with its standard error, the ratio of the
 * scatters, and the CPU time of each readout.
 * usage: bench_direct_error NPIX MA_TABLE [direct|moments [RATE,RATE,...]]
 * (the mode compared with per-read, direct by default; rates in e-/s, 1,30,300,3000 by default) */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "hal/scene.h"
#include "tools/assemble.h"
#include "tools/expose.h"

static double cpu_now(void) { return (double)clock() / CLOCKS_PER_SEC; }

/* Runs one exposure and returns the mean and standard deviation of SCI over the interior. */
static int run(int n, const char *ma, double rate, int nl, wf_sampling sampling, double *mean,
               double *sd, double *cpu)
{
    wf_expose_job job = {0};
    wf_readout_config *ro = &job.ro;
    ro->ncols = ro->nrows = n;
    ro->tile_rows = 64;
    ro->mode = WF_MODE_RAMP;
    ro->sampling = sampling;
    ro->exposure = 1;
    ro->sca = 1;
    ro->seed = 99;
    wf_detector_defaults(&ro->det);
    ro->det.on.cosmic_rays = 0;
    ro->det.on.nonlinearity = nl;
    job.clock.frame_time = WF_FRAME_TIME_DEFAULT;
    if (wf_ma_resolve(ma, &job.clock.ma)) return 1;
    job.threads = 1;
    job.noise = (wf_noise){WF_NOISE_PHILOX, 99, 1, 1};
    wf_scene_grid grid = {n, n, rate, 0.0, 1.0, 1 << 20};
    wf_scene_source src;
    wf_scene_grid_source(&grid, &src);
    job.scenes = &src;
    wf_link_memory mem;
    wf_link link;
    wf_link_memory_open(&mem, &link);
    job.link = &link;
    double c0 = cpu_now();
    if (wf_expose_run(&job)) { fprintf(stderr, "%s\n", wf_error_message()); return 1; }
    *cpu = cpu_now() - c0;
    char dir[] = "/tmp/wfisim-bench-XXXXXX";
    if (!mkdtemp(dir)) return 1;
    FILE *f = fmemopen(mem.data, mem.len, "rb");
    wf_assemble_options opt = {.out_dir = dir, .quiet = 1};
    char path[1024];
    wf_status st = wf_assemble_stream(f, "bench", &opt, path, sizeof path);
    fclose(f);
    wf_link_memory_close(&mem);
    if (st) { fprintf(stderr, "%s\n", wf_error_message()); return 1; }
    fitsfile *ff;
    int status = 0;
    float *sci = malloc(sizeof *sci * (size_t)n * n);
    long first[2] = {1, 1};
    fits_open_file(&ff, path, READONLY, &status);
    fits_movnam_hdu(ff, IMAGE_HDU, "SCI", 0, &status);
    fits_read_pix(ff, TFLOAT, first, (long long)n * n, NULL, sci, NULL, &status);
    fits_close_file(ff, &status);
    remove(path);
    rmdir(dir);
    double s = 0, s2 = 0;
    long cnt = 0;
    for (int y = 1; y < n - 1; y++)
        for (int x = 1; x < n - 1; x++) {
            double v = sci[(size_t)y * n + x];
            s += v;
            s2 += v * v;
            cnt++;
        }
    free(sci);
    *mean = s / cnt;
    *sd = sqrt(s2 / cnt - *mean * *mean);
    return status;
}

int main(int argc, char **argv)
{
    int n = argc > 1 ? atoi(argv[1]) : 256;
    const char *ma = argc > 2 ? argv[2] : "6";
    const char *mode = argc > 3 ? argv[3] : "direct";
    wf_sampling other = WF_SAMPLE_DIRECT;
    if (!strcmp(mode, "moments")) other = WF_SAMPLE_MOMENTS;
    else if (strcmp(mode, "direct")) { fprintf(stderr, "mode %s: direct or moments\n", mode); return 2; }
    double rates[16] = {1.0, 30.0, 300.0, 3000.0};
    int nrates = 4;
    if (argc > 4) {
        nrates = 0;
        for (char *p = argv[4]; *p && nrates < 16; p += *p == ',') rates[nrates++] = strtod(p, &p);
    }
    printf("| MA table | rate e-/s | NL | per-read mean | %s mean | %s - per-read (rel.) | "
           "std. error (rel.) | scatter ratio | CPU s per-read | CPU s %s |\n", mode, mode, mode);
    printf("|---|---|---|---|---|---|---|---|---|---|\n");
    for (int nl = 0; nl <= 1; nl++)
        for (int i = 0; i < nrates; i++) {
            double m[2], sd[2], cpu[2];
            for (int s = 0; s < 2; s++)
                if (run(n, ma, rates[i], nl, s ? other : WF_SAMPLE_PER_READ, &m[s], &sd[s], &cpu[s]))
                    return 1;
            long cnt = (long)(n - 2) * (n - 2);
            double se = sqrt((sd[0] * sd[0] + sd[1] * sd[1]) / cnt) / m[0];
            printf("| %s | %g | %s | %.5f | %.5f | %+.2e | %.1e | %.4f | %.2f | %.2f |\n", ma, rates[i],
                   nl ? "on" : "off", m[0], m[1], (m[1] - m[0]) / m[0], se, sd[1] / sd[0], cpu[0], cpu[1]);
            fflush(stdout);
        }
    return 0;
}
