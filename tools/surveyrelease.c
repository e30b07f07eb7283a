#include "tools/surveyrelease.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "sim/survey/catalog.h"
#include "sim/sn/sncat.h"
#include "tools/pipeline.h"
#include "tools/sncmd.h"

static void unit(double ra, double dec, double v[3])
{
    const double r = M_PI / 180.0;
    v[0] = cos(dec * r) * cos(ra * r);
    v[1] = cos(dec * r) * sin(ra * r);
    v[2] = sin(dec * r);
}

static double angle(const double a[3], const double b[3])
{
    double c[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) * 180.0 / M_PI;
}

/* A circle holding every SCA of the run: about the --area centre, else the mean direction of
 * the SCA centres, out to the farthest SCA centre plus a full SCA's half diagonal (4088 pixels
 * of at most 0.11": 0.088 deg, taken as 0.1) plus the 70" a stamp reaches. */
static wf_status release_circle(const double *area, const wf_survey_index_row *rows, size_t n, double *ra,
                                double *dec, double *radius)
{
    double c[3] = {0, 0, 0}, v[3];
    if (area) unit(area[0], area[1], c);
    else
        for (size_t i = 0; i < n; i++) {
            unit(rows[i].ra_sca, rows[i].dec_sca, v);
            for (int k = 0; k < 3; k++) c[k] += v[k];
        }
    double norm = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    if (!(norm > 0)) return wf_error(WF_ERR_INPUT, "the run's SCAs surround the sphere: no circle holds them");
    *ra = fmod(atan2(c[1], c[0]) * 180.0 / M_PI + 360.0, 360.0);
    *dec = asin(c[2] / norm) * 180.0 / M_PI;
    double far = 0;
    for (size_t i = 0; i < n; i++) {
        unit(rows[i].ra_sca, rows[i].dec_sca, v);
        double a = angle(c, v);
        if (a > far) far = a;
    }
    *radius = far + 0.1 + 70.0 / 3600.0;
    if (*radius >= 90.0) return wf_error(WF_ERR_INPUT, "the run's SCAs span more than a hemisphere");
    return WF_OK;
}

wf_status wf_survey_write_release(const wf_config *cfg, const char *plan, const char *sne, const char *sne_model,
                                  const double *area, const wf_survey_index_row *rows, size_t n, char *note,
                                  size_t cap)
{
    double ra = 0, dec = 0, radius = 0;
    wf_status st = release_circle(area, rows, n, &ra, &dec, &radius);
    wf_skyregion reg;
    if (!st) st = wf_skyindex_circle(ra, dec, radius, 0.0, &reg);
    wf_scene_inputs in;
    memset(&in, 0, sizeof in);
    if (!st) st = wf_pipeline_load_catalogs_in(cfg, &reg, &in);
    char path[WF_PATH_MAX + 64];
    if (!st && in.have_gal) {
        snprintf(path, sizeof path, "%s/input_galaxies.fits", cfg->out_dir);
        st = wf_catalog_write_fits(path, &in.gal);
    }
    if (!st && in.have_stars) {
        snprintf(path, sizeof path, "%s/input_stars.fits", cfg->out_dir);
        st = wf_catalog_write_fits(path, &in.stars);
    }
    size_t ngal = in.have_gal ? in.gal.n : 0, nstars = in.have_stars ? in.stars.n : 0;
    wf_pipeline_inputs_free(&in);
    wf_sn_sample s;
    if (!st && !(st = wf_sn_sample_read(sne, &s))) {
        snprintf(path, sizeof path, "%s/sne.fits", cfg->out_dir);
        st = wf_sn_sample_write(&s, path);
        wf_sn_sample_free(&s);
    }
    size_t points = 0;
    if (!st) {
        snprintf(path, sizeof path, "%s/sn_lightcurves.fits", cfg->out_dir);
        st = wf_sn_write_plan_lightcurves(sne, plan, sne_model, cfg->data_dir, path, &points);
    }
    if (!st)
        snprintf(note, cap,
                 "release.catalogs = input_galaxies.fits (%zu), input_stars.fits (%zu): within %.6f deg of "
                 "RA %.6f Dec %.6f\nrelease.sne = sne.fits, sn_lightcurves.fits (%zu points)\n",
                 ngal, nstars, radius, ra, dec, points);
    return st;
}
