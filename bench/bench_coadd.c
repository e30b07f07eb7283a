/* Writes n synthetic products for the coadd benchmark: SIZE x SIZE pixels of SCA 1 about its
 * centre, Y106, sky 0.5 e-/s with Gaussian noise, ERR from it, 1 pixel in 500 flagged, each
 * at a dithered pointing (offsets up to 20 arcsec, PA within a degree: a deep-field visit's
 * dithers) with the SCA's WCS from sim/survey/wcs.h. Prints the pointing's centre as "RA,DEC".
 *   usage: bench_coadd DIR N SIZE */
#include <fitsio.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/survey/wcs.h"

int main(int argc, char **argv)
{
    if (argc != 4) {
        fprintf(stderr, "usage: bench_coadd DIR N SIZE\n");
        return 2;
    }
    const char *dir = argv[1];
    int n = atoi(argv[2]), size = atoi(argv[3]);
    if (n < 1 || size < 16 || size > WF_WCS_NPIX) {
        fprintf(stderr, "bench_coadd: bad N or SIZE\n");
        return 2;
    }
    wf_focal_plane fp;
    wf_wcs_focal_plane_builtin(&fp);
    size_t np = (size_t)size * size;
    float *sci = malloc(np * sizeof *sci), *err = malloc(np * sizeof *err);
    unsigned *dq = malloc(np * sizeof *dq);
    if (!sci || !err || !dq) return 1;
    srand(1);
    double cra = 0, cdec = 0;
    for (int e = 0; e < n; e++) {
        double ra = 71.0 + (rand() / (double)RAND_MAX - 0.5) * 40 / 3600 / cos(53 * M_PI / 180);
        double dec = -53.0 + (rand() / (double)RAND_MAX - 0.5) * 40 / 3600;
        double pa = 30.0 + (rand() / (double)RAND_MAX - 0.5) * 2;
        wf_wcs w;
        if (wf_wcs_for_sca(&fp, ra, dec, pa, 1, &w)) return 1;
        /* the subarray about the SCA's centre */
        w.nx = w.ny = size;
        w.crpix[0] = w.crpix[1] = size / 2;
        if (e == 0) {
            cra = w.crval[0];
            cdec = w.crval[1];
        }
        for (size_t k = 0; k < np; k++) {
            double u1 = (rand() + 1.0) / (RAND_MAX + 2.0), u2 = rand() / (double)RAND_MAX;
            sci[k] = (float)(0.5 + 0.05 * sqrt(-2 * log(u1)) * cos(2 * M_PI * u2));
            err[k] = 0.05f;
            dq[k] = rand() % 500 == 0 ? 4u : 0u;
        }
        char path[1024];
        snprintf(path, sizeof path, "!%s/wfisim_e%06d_sca01.fits", dir, e + 1);
        fitsfile *f;
        int status = 0;
        long naxes[2] = {size, size};
        fits_create_file(&f, path, &status);
        fits_create_img(f, BYTE_IMG, 0, NULL, &status);
        fits_write_key_str(f, "FILTER", "Y106", "", &status);
        fits_write_key_lng(f, "EXPOSURE", e + 1, "", &status);
        fits_write_key_lng(f, "SCA", 1, "", &status);
        fits_write_key_dbl(f, "MJD-OBS", 61420.0 + e, 12, "", &status);
        const char *names[3] = {"SCI", "ERR", "DQ"};
        for (int h = 0; h < 3 && !status; h++) {
            fits_create_img(f, h == 2 ? ULONG_IMG : FLOAT_IMG, 2, naxes, &status);
            fits_write_key_str(f, "EXTNAME", (char *)names[h], "", &status);
            if (!status && wf_wcs_write_header(&w, f, path)) return 1;
            if (h == 2) fits_write_img(f, TUINT, 1, (LONGLONG)np, dq, &status);
            else fits_write_img(f, TFLOAT, 1, (LONGLONG)np, h ? err : sci, &status);
        }
        fits_close_file(f, &status);
        if (status) {
            fits_report_error(stderr, status);
            return 1;
        }
    }
    printf("%.9f,%.9f\n", cra, cdec);
    free(sci);
    free(err);
    free(dq);
    return 0;
}
