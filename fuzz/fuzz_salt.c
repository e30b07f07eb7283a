/* SALT model files (sim/sn/salt.c). A model is three files in one directory, so an input is a
 * small archive: template_0, template_1 and color_correction in that order, separated by
 * lines "%%" (fewer parts leave the later files absent). The model that loads is then used
 * as the light-curve code uses it: colour law, flux on and off the grid by both
 * interpolations, band rates and the fast light curve through a top-hat Y106 band. */
#include <stdio.h>
#include <string.h>

#include "fuzz/common.h"
#include "sim/sn/salt.h"

static const char *const part_name[3] = {"salt3_template_0.dat", "salt3_template_1.dat",
                                         "salt3_color_correction.dat"};

static void exercise(const wf_salt_model *m)
{
    double p0, p1, w0, w1;
    wf_salt_phase_range(m, &p0, &p1);
    wf_salt_wave_range(m, &w0, &w1);
    const wf_salt_params par = {.z = 0.4, .t0 = 61500.0, .x0 = 1e-5, .x1 = 0.5, .c = 0.1};
    for (int i = -1; i <= 5; i++)
        for (int j = -1; j <= 5; j++) {
            double p = p0 + (p1 - p0) * i / 4.0, w = w0 + (w1 - w0) * j / 4.0, f;
            (void)wf_salt_colorlaw(m, w);
            (void)wf_salt_flux(m, &par, WF_SALT_INTERP_BICUBIC, p, w, &f);
            (void)wf_salt_flux(m, &par, WF_SALT_INTERP_LINEAR, p, w, &f);
        }
    wf_bandpass bp;
    if (wf_bandpass_tophat(WF_Y106, &bp) != WF_OK) return;
    double rate, mag;
    unsigned flags;
    (void)wf_salt_bandmag(m, &par, WF_SALT_INTERP_BICUBIC, &bp, par.t0, &mag, &flags);
    wf_salt_lc *lc;
    if (wf_salt_lc_init(m, &par, &bp, WF_SALT_INTERP_BICUBIC, &lc) == WF_OK) {
        double t0, t1;
        int covered;
        wf_salt_lc_window(lc, &t0, &t1, &covered);
        for (int k = -1; k <= 9; k++) {
            (void)wf_salt_lc_rate(lc, t0 + (t1 - t0) * k / 8.0, &rate, &flags);
            (void)wf_salt_lc_mag(lc, t0 + (t1 - t0) * k / 8.0, &mag, &flags);
        }
        wf_salt_lc_free(lc);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    const uint8_t *p = data, *end = data + size;
    for (int k = 0; k < 3; k++) {
        snprintf(path, sizeof path, "%s/%s", fz_dir(), part_name[k]);
        remove(path);
    }
    for (int k = 0; k < 3 && p <= end; k++) {
        const uint8_t *cut = NULL;
        for (const uint8_t *q = p; q + 4 <= end && !cut; q++)
            if (!memcmp(q, "\n%%\n", 4)) cut = q;
        size_t len = cut ? (size_t)(cut + 1 - p) : (size_t)(end - p);
        fz_write(part_name[k], p, len, path);
        if (!cut) break;
        p = cut + 4;
    }
    wf_salt_model *m = NULL;
    if (wf_salt_load(fz_dir(), &m) == WF_OK) {
        exercise(m);
        wf_salt_free(m);
    }
    return 0;
}
