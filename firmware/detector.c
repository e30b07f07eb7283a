#include "firmware/detector.h"

#include <math.h>
#include <string.h>

/* SPEC §2 (GalSim ipc_kernel), before normalisation. */
static const double ipc_raw[3][3] = {{0.001269938, 0.015399776, 0.001199862},
                                     {0.013800177, 1.0, 0.015600367},
                                     {0.001270391, 0.016129619, 0.001200137}};

void wf_detector_ipc_default(double out[3][3])
{
    double sum = 0.0;
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) sum += ipc_raw[a][b];
    for (int a = 0; a < 3; a++)
        for (int b = 0; b < 3; b++) out[a][b] = ipc_raw[a][b] / sum;
}

void wf_detector_defaults(wf_detector *det)
{
    memset(det, 0, sizeof *det);
    det->on.photon_noise = det->on.reciprocity = det->on.dark = det->on.nonlinearity = 1;
    det->on.ipc = det->on.read_noise = det->on.quantize = det->on.saturation = 1;
    det->on.cosmic_rays = 1;
    det->dark_current = 0.015;
    det->read_noise_e = 8.5;
    det->gain = 1.0;
    det->nl_beta = -6.0e-7;
    det->recip_alpha = 0.0065;
    det->recip_f0 = 1.0;
    wf_detector_ipc_default(det->ipc);
    det->full_well = 1.0e5;
    det->adc_max = 65535.0;
    det->bias_adu = 1000.0;
    det->cr_rate = 8.0;
    det->pixel_um = 10.0;
    det->depth_um = 5.0;
    det->cr_lmin_um = 10.0;
    det->cr_lmax_um = 2000.0;
    det->cr_slope = -4.33;
    det->cr_dedx_loc = 120.0;
    det->cr_dedx_scale = 50.0;
    det->cr_ev_per_e = 3.8; /* romanisim cr.py "gain" of 3.8 eV per count */
}

double wf_det_reciprocity(double q, double exptime, double alpha, double f0)
{
    if (!(q > 0.0))
        return q;
    return q * pow(q / (exptime * f0), alpha / M_LN10);
}

double wf_det_reciprocity_rate(double rate, double alpha, double f0)
{
    if (!(rate > 0.0))
        return rate;
    return rate * pow(rate / f0, alpha / M_LN10);
}

void wf_det_ipc_row(const double *above, const double *row, const double *below, int ncols,
                    const double k[3][3], double *out)
{
    const double *in[3] = {above, row, below};
    if (ncols <= 0)
        return; /* the edge terms below would touch out[0], out[-1] and r[1] */
    for (int x = 0; x < ncols; x++) out[x] = 0.0;
    for (int a = 0; a < 3; a++) {
        const double *r = in[a];
        if (!r) continue;
        const double k0 = k[a][0], k1 = k[a][1], k2 = k[a][2];
        /* interior: all three columns exist */
        for (int x = 1; x < ncols - 1; x++)
            out[x] += k0 * r[x - 1] + k1 * r[x] + k2 * r[x + 1];
        if (ncols == 1) {
            out[0] += k1 * r[0];
            continue;
        }
        out[0] += k1 * r[0] + k2 * r[1];
        out[ncols - 1] += k0 * r[ncols - 2] + k1 * r[ncols - 1];
    }
}


double wf_det_saturation_adu(const wf_detector *det)
{
    double fw = det->full_well;
    if (det->on.nonlinearity) fw = wf_det_nonlinearity(fw, det->nl_beta);
    double adu = fw / det->gain + det->bias_adu;
    return adu < det->adc_max ? adu : det->adc_max;
}
