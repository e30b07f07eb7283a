/* Survey-scale costs that no single command shows:
 *   bench_survey select [DATA]           footprint selection of all 18 SCAs of one pointing
 *                                        out of the whole synthetic field (≈2.7 M galaxies):
 *                                        sky index build once, then per-SCA queries; and the
 *                                        generator's own per-SCA path (cells under the SCA only)
 *   bench_survey inject PLAN SNE MODEL [DATA] [NEXP]
 *                                        SN injection: for NEXP exposures of the plan and all 18
 *                                        SCAs, the SNe in each footprint and their magnitudes
 * Prints "key=value" fields on one line per case. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <fitsio.h>

#include "sim/survey/skyindex.h"
#include "sim/survey/synth.h"
#include "sim/survey/wcs.h"
#include "tools/sninject.h"

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static double cpu(void)
{
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int die(const char *what)
{
    fprintf(stderr, "bench_survey: %s: %s\n", what, wf_error_message());
    return 1;
}

static wf_status sca_region(const wf_focal_plane *fp, double ra, double dec, double pa, int sca, wf_skyregion *reg)
{
    wf_wcs w;
    wf_status st = wf_wcs_for_sca(fp, ra, dec, pa, sca, &w);
    if (st) return st;
    double r[4], d[4];
    const double cx[4] = {-0.5, 4087.5, 4087.5, -0.5}, cy[4] = {-0.5, -0.5, 4087.5, 4087.5};
    for (int k = 0; k < 4; k++)
        if ((st = wf_wcs_pix2world(&w, cx[k], cy[k], &r[k], &d[k]))) return st;
    return wf_skyindex_polygon(r, d, 4, 70.0, reg);
}

static int bench_select(const char *data)
{
    wf_focal_plane fp;
    if (wf_wcs_focal_plane(data, &fp)) return die("focal plane");
    wf_synth_config sc;
    wf_synth *syn;
    wf_synth_defaults(&sc);
    if (wf_synth_create(&sc, &syn)) return die("synth");
    wf_catalog gal;
    double t0 = now(), c0 = cpu();
    if (wf_synth_generate_all(syn, &gal, NULL)) return die("generate");
    double gen = cpu() - c0;
    wf_skyindex *ix;
    c0 = cpu();
    if (wf_skyindex_build(gal.ra, gal.dec, gal.n, 1.0, &ix)) return die("index");
    double build = cpu() - c0;
    wf_selection sel = {0};
    size_t total = 0;
    c0 = cpu();
    const int reps = 20;
    for (int r = 0; r < reps; r++)
        for (int s = 1; s <= 18; s++) {
            wf_skyregion reg;
            if (sca_region(&fp, 71.0, -53.0, 30.0, s, &reg) || wf_skyindex_select(ix, &reg, &sel)) return die("select");
            if (!r) total += sel.n;
        }
    double per_sca_ms = (cpu() - c0) / (reps * 18) * 1e3;
    printf("case=index galaxies=%zu generate_cpu_s=%.2f index_build_cpu_s=%.3f select_ms_per_sca=%.3f "
           "mean_galaxies_per_sca=%.0f\n", gal.n, gen, build, per_sca_ms, total / 18.0);
    /* the generator's path: only the cells under the SCA */
    c0 = cpu();
    size_t n2 = 0;
    for (int s = 1; s <= 18; s++) {
        wf_skyregion reg;
        wf_catalog g;
        if (sca_region(&fp, 71.0, -53.0, 30.0, s, &reg) || wf_synth_select(syn, &reg, &g, NULL)) return die("synth select");
        n2 += g.n;
        wf_catalog_free(&g);
    }
    printf("case=synth_select ms_per_sca=%.1f mean_galaxies_per_sca=%.0f\n", (cpu() - c0) / 18 * 1e3, n2 / 18.0);
    (void)t0;
    wf_skyindex_selection_free(&sel);
    wf_skyindex_free(ix);
    wf_catalog_free(&gal);
    wf_synth_free(syn);
    return 0;
}

static int bench_inject(const char *plan, const char *sne, const char *model, const char *data, long nexp)
{
    wf_focal_plane fp;
    if (wf_wcs_focal_plane(data, &fp)) return die("focal plane");
    fitsfile *f;
    int status = 0, c[5];
    long nrows;
    fits_open_file(&f, plan, READONLY, &status);
    fits_movnam_hdu(f, BINARY_TBL, "PLAN", 0, &status);
    const char *names[5] = {"RA", "DEC", "PA", "MJD_MID", "FILTER"};
    for (int k = 0; k < 5; k++) fits_get_colnum(f, CASEINSEN, (char *)names[k], &c[k], &status);
    fits_get_num_rows(f, &nrows, &status);
    if (status) { fprintf(stderr, "bench_survey: %s: cannot read the plan\n", plan); return 1; }
    if (nexp > nrows) nexp = nrows;
    wf_sn_injector *inj;
    double c0 = cpu();
    if (wf_sn_injector_open(sne, model, data, &inj)) return die("injector");
    double open_s = cpu() - c0;
    long images = 0, sne_seen = 0, lit = 0;
    double t_select = 0;
    /* spread the exposures over the survey: every (nrows / nexp)-th */
    long stride = nrows / nexp > 0 ? nrows / nexp : 1;
    for (long e = 0; e < nexp; e++) {
        long row = 1 + e * stride;
        double ra, dec, pa, mjd;
        char filt[16], *fpn = filt;
        fits_read_col(f, TDOUBLE, c[0], row, 1, 1, NULL, &ra, NULL, &status);
        fits_read_col(f, TDOUBLE, c[1], row, 1, 1, NULL, &dec, NULL, &status);
        fits_read_col(f, TDOUBLE, c[2], row, 1, 1, NULL, &pa, NULL, &status);
        fits_read_col(f, TDOUBLE, c[3], row, 1, 1, NULL, &mjd, NULL, &status);
        fits_read_col(f, TSTRING, c[4], row, 1, 1, NULL, &fpn, NULL, &status);
        for (int s = 1; s <= 18; s++) {
            wf_skyregion reg;
            wf_scene_sn *v;
            size_t n;
            if (sca_region(&fp, ra, dec, pa, s, &reg)) return die("region");
            double a = cpu();
            if (wf_sn_injector_select(inj, filt, mjd, &reg, &v, &n)) return die("select");
            t_select += cpu() - a;
            images++;
            sne_seen += (long)n;
            for (size_t k = 0; k < n; k++) lit += v[k].mag < 99.0;
            free(v);
        }
    }
    int cs = 0;
    fits_close_file(f, &cs);
    printf("case=inject images=%ld sne_in_footprints=%ld sne_with_light=%ld open_cpu_s=%.3f "
           "select_us_per_image=%.1f select_us_per_sn=%.2f\n", images, sne_seen, lit, open_s,
           t_select / images * 1e6, sne_seen ? t_select / sne_seen * 1e6 : 0.0);
    wf_sn_injector_free(inj);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc >= 2 && !strcmp(argv[1], "select")) return bench_select(argc > 2 ? argv[2] : NULL);
    if (argc >= 5 && !strcmp(argv[1], "inject"))
        return bench_inject(argv[2], argv[3], argv[4], argc > 5 ? argv[5] : "", argc > 6 ? atol(argv[6]) : 200);
    fprintf(stderr, "usage: bench_survey select [DATA] | inject PLAN SNE MODEL [DATA] [NEXP]\n");
    return 2;
}
