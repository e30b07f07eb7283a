/* Draws every object of GalSim's benchmark scene (SCA 1, pointing A, Y106) once, as the
 * renderer draws it, and reports the CPU time per kind and stamp size: the cost of the
 * profile drawer alone, without the detector chain.
 *
 *   bench_profile [--dump FILE] [--compare FILE] [--limit N] [--simd LANES] [--core R]
 *                 [--levels L] [--tol T]
 *
 * --dump writes every stamp (bounds and pixels) so that a later build can be compared with
 * --compare: per object the worst pixel difference over the stamp's peak, and the flux.
 * --simd caps the vector width of the drawing kernels (0: scalar; they all give the same
 * bits, which --dump / --compare across widths shows). --core sets psf.core_radius
 * (arcsec; 0: the whole PSF in every Fourier box), --levels psf.core_levels, --tol scene.noise_tolerance (0: the same
 * knobs for every object); --compare then also gives differences in sky sigma.
 * Data: $WFISIM_DATA (default ../shared/data) and $WFISIM_REFERENCE (../shared/reference). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "sim/draw/profile_int.h"
#include "tools/config.h"
#include "tools/pipeline.h"

static double cpu_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int fail(const char *what)
{
    fprintf(stderr, "bench_profile: %s: %s\n", what, wf_error_message());
    return 1;
}

typedef struct rec {
    int kind, x0, y0, nx, ny;
    double ms, sum, peak;
} rec;

int main(int argc, char **argv)
{
    const char *dump = NULL, *compare = NULL;
    long limit = -1;
    int simd = -1;
    double core = -1.0, tol = -1.0;
    int levels = 0, synthetic = 0;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--dump") && i + 1 < argc) dump = argv[++i];
        else if (!strcmp(argv[i], "--compare") && i + 1 < argc) compare = argv[++i];
        else if (!strcmp(argv[i], "--limit") && i + 1 < argc) limit = atol(argv[++i]);
        else if (!strcmp(argv[i], "--simd") && i + 1 < argc) simd = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--core") && i + 1 < argc) core = atof(argv[++i]);
        else if (!strcmp(argv[i], "--tol") && i + 1 < argc) tol = atof(argv[++i]);
        else if (!strcmp(argv[i], "--levels") && i + 1 < argc) levels = atoi(argv[++i]);
        else if (!strcmp(argv[i], "--synthetic")) synthetic = 1;
        else {
            fprintf(stderr, "usage: bench_profile [--dump FILE] [--compare FILE] [--limit N] "
                            "[--simd LANES] [--core R] [--levels L] [--tol T] [--synthetic]\n");
            return 2;
        }
    }
    int lanes = wf_profile_simd(simd);
    const char *data = getenv("WFISIM_DATA"), *ref = getenv("WFISIM_REFERENCE");
    if (!data) data = "../shared/data";
    if (!ref) ref = "../shared/reference";
    wf_config cfg;
    wf_clock clock;
    char set[2 * WF_PATH_MAX];
    wf_config_defaults(&cfg);
    snprintf(set, sizeof set, "paths.data=%s", data);
    if (wf_config_set(&cfg, set, NULL) ||
        wf_config_set(&cfg, synthetic ? "scene.kind=synthetic" : "scene.kind=galsim", NULL))
        return fail("config");
    snprintf(set, sizeof set, "scene.catalog=%s/galsim/scene_catalog_sca1_pointingA.csv.gz", ref);
    if ((!synthetic && wf_config_set(&cfg, set, NULL)) || wf_config_finish(&cfg, &clock))
        return fail("config");

    wf_scene_inputs in;
    memset(&in, 0, sizeof in);
    if (wf_pipeline_load_catalogs(&cfg, &in)) return fail("catalogs");
    wf_scene_setup ss;
    wf_scene_setup_default(&ss);
    ss.ra = cfg.ra;
    ss.dec = cfg.dec;
    ss.pa = cfg.pa;
    ss.sca = (int)cfg.ro.sca;
    snprintf(ss.filter, sizeof ss.filter, "%s", cfg.filter);
    ss.mjd = cfg.mjd;
    snprintf(ss.data_dir, sizeof ss.data_dir, "%s", cfg.data_dir);
    ss.ncols = cfg.ro.ncols;
    ss.nrows = cfg.ro.nrows;
    ss.pupil_bin = 1 << cfg.pupil_bin;
    ss.psf_oversample = cfg.psf_oversample;
    ss.psf_nlambda = cfg.psf_nlambda;
    ss.flux_fraction = cfg.flux_fraction;
    ss.core_radius = core >= 0.0 ? core : cfg.psf_core_radius;
    ss.core_levels = levels > 0 ? levels : cfg.psf_core_levels;
    ss.noise_tolerance = tol >= 0.0 ? tol : cfg.noise_tolerance;
    ss.exptime = cfg.ro.exptime;
    ss.threads = 1;
    wf_scene *scene;
    double t0 = cpu_now();
    if (wf_scene_create(&ss, in.have_gal ? &in.gal : NULL, in.have_stars ? &in.stars : NULL,
                        &scene))
        return fail("scene");
    double t_build = cpu_now() - t0;
    size_t n = wf_scene_object_count(scene);
    if (limit >= 0 && (size_t)limit < n) n = (size_t)limit;
    rec *r = calloc(n ? n : 1, sizeof *r);
    FILE *fd = dump ? fopen(dump, "wb") : NULL, *fc = compare ? fopen(compare, "rb") : NULL;
    if (!r || (dump && !fd) || (compare && !fc)) {
        fprintf(stderr, "bench_profile: cannot open the dump files or allocate\n");
        return 1;
    }
    /* differences also in units of one pixel's sky noise over the exposure (e-), the unit of
     * scene.noise_tolerance */
    wf_scene_stats sst;
    wf_scene_get_stats(scene, &sst);
    const double sigma_rate = sqrt(sst.sky_min * ss.exptime) / ss.exptime;
    double worst = 0.0, worst_flux = 0.0, total = 0.0, worst_sigma = 0.0;
    size_t worst_k = 0, worst_sk = 0, mismatched = 0, identical = 0;
    for (size_t k = 0; k < n; k++) {
        wf_scene_object info;
        int x0, y0, nx, ny;
        double *pix;
        double a = cpu_now();
        if (wf_scene_draw_object(scene, k, &info, &x0, &y0, &nx, &ny, &pix)) return fail("draw");
        double b = cpu_now();
        size_t np = (size_t)nx * ny;
        double sum = 0.0, peak = 0.0;
        for (size_t i = 0; i < np; i++) {
            sum += pix[i];
            if (pix[i] > peak) peak = pix[i];
        }
        r[k] = (rec){info.kind, x0, y0, nx, ny, 1e3 * (b - a), sum, peak};
        total += b - a;
        if (fd) {
            int h[4] = {x0, y0, nx, ny};
            fwrite(h, sizeof h, 1, fd);
            fwrite(pix, sizeof *pix, np, fd);
        }
        if (fc) {
            /* the two stamps over the union of their bounds, zero outside each */
            int h[4];
            if (fread(h, sizeof h, 1, fc) != 1 || h[2] < 0 || h[3] < 0) return fail("compare read");
            size_t on = (size_t)h[2] * h[3];
            double *o = malloc((on ? on : 1) * sizeof *o);
            if (!o || fread(o, sizeof *o, on, fc) != on) return fail("compare read");
            if (h[0] != x0 || h[1] != y0 || h[2] != nx || h[3] != ny) mismatched++;
            else if (!memcmp(o, pix, np * sizeof *o)) identical++;
            int ux0 = x0 < h[0] ? x0 : h[0], uy0 = y0 < h[1] ? y0 : h[1];
            int ux1 = x0 + nx > h[0] + h[2] ? x0 + nx : h[0] + h[2];
            int uy1 = y0 + ny > h[1] + h[3] ? y0 + ny : h[1] + h[3];
            double d = 0.0, osum = 0.0, opeak = 0.0;
            for (size_t i = 0; i < on; i++) {
                osum += o[i];
                opeak = fmax(opeak, o[i]);
            }
            for (int yy = uy0; yy < uy1; yy++)
                for (int xx = ux0; xx < ux1; xx++) {
                    int in1 = xx >= x0 && xx < x0 + nx && yy >= y0 && yy < y0 + ny;
                    int in0 = xx >= h[0] && xx < h[0] + h[2] && yy >= h[1] && yy < h[1] + h[3];
                    double a1 = in1 ? pix[(size_t)(yy - y0) * nx + (xx - x0)] : 0.0;
                    double a0 = in0 ? o[(size_t)(yy - h[1]) * h[2] + (xx - h[0])] : 0.0;
                    d = fmax(d, fabs(a1 - a0));
                }
            double rel = opeak > 0.0 ? d / opeak : d;
            if (d / sigma_rate > worst_sigma) {
                worst_sigma = d / sigma_rate;
                worst_sk = k;
            }
            if (rel > worst) {
                worst = rel;
                worst_k = k;
            }
            if (osum > 0.0) worst_flux = fmax(worst_flux, fabs(sum - osum) / osum);
            free(o);
        }
        free(pix);
    }
    /* by kind and by stamp side */
    static const int edges[] = {0, 48, 96, 192, 384, 768, 1 << 30};
    printf("bench_profile: %zu objects, scene build %.2f CPU-s, draws %.3f CPU-s (%d-lane "
           "kernels); %ld of %ld galaxies with the split PSF, %ld with smooth knots\n", n, t_build, total,
           lanes, sst.split, sst.galaxies, sst.knots_smooth);
    for (int kind = 0; kind < 3; kind++) {
        for (int e = 0; e + 1 < (int)(sizeof edges / sizeof *edges); e++) {
            long c = 0;
            double ms = 0.0;
            for (size_t k = 0; k < n; k++)
                if (r[k].kind == kind && r[k].nx >= edges[e] && r[k].nx < edges[e + 1]) {
                    c++;
                    ms += r[k].ms;
                }
            if (c)
                printf("  %-6s stamp %4d..%-4d: %5ld objects, %8.1f ms, %7.3f ms each\n",
                       kind == 0 ? "galaxy" : kind == 1 ? "star" : "sn", edges[e],
                       edges[e + 1] > 100000 ? 99999 : edges[e + 1] - 1, c, ms, ms / c);
        }
    }
    if (compare)
        printf("compare: %zu identical of %zu, worst pixel / peak %.3g (object %zu), worst "
               "pixel / sky sigma %.3g (object %zu, %s), worst |dflux|/flux %.3g%s\n",
               identical, n, worst, worst_k, worst_sigma, worst_sk,
               r[worst_sk].kind == 0 ? "galaxy" : r[worst_sk].kind == 1 ? "star" : "sn", worst_flux,
               mismatched ? " (bounds differ for some: compared over the union)" : "");
    if (fd) fclose(fd);
    if (fc) fclose(fc);
    free(r);
    wf_scene_destroy(scene);
    wf_pipeline_inputs_free(&in);
    return 0;
}
