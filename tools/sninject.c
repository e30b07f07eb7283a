#include "tools/sninject.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/optics/bandpass.h"
#include "sim/sn/salt.h"
#include "sim/sn/sncat.h"

/* One light curve per (SN, filter), built on first use: the per-SN band integrals make every
 * later date cost a phase interpolation. */
typedef struct lc_slot {
    wf_salt_lc *lc; /* NULL until first used */
} lc_slot;

struct wf_sn_injector {
    wf_sn_sample sample;
    wf_salt_model *model;
    char data_dir[1024];
    char sample_path[1024], model_dir[1024]; /* for the products' input digest */
    wf_bandpass *bp[WF_NFILTER];
    lc_slot *slots[WF_NFILTER]; /* [filter][sn] */
    wf_skyindex *index;
    double phase_min, phase_max; /* rest-frame days the model covers */
};

wf_status wf_sn_injector_open(const char *sne_path, const char *model_dir, const char *data_dir,
                              wf_sn_injector **out)
{
    *out = NULL;
    wf_sn_injector *inj = calloc(1, sizeof *inj);
    if (!inj) return wf_error(WF_ERR_NOMEM, "SN injector: out of memory");
    snprintf(inj->data_dir, sizeof inj->data_dir, "%s", data_dir ? data_dir : "");
    snprintf(inj->sample_path, sizeof inj->sample_path, "%s", sne_path);
    snprintf(inj->model_dir, sizeof inj->model_dir, "%s", model_dir);
    wf_status st = wf_sn_sample_read(sne_path, &inj->sample);
    if (!st) st = wf_salt_load(model_dir, &inj->model);
    if (!st) wf_salt_phase_range(inj->model, &inj->phase_min, &inj->phase_max);
    if (!st && inj->sample.n)
        st = wf_skyindex_build(inj->sample.ra, inj->sample.dec, inj->sample.n, 1.0, &inj->index);
    if (st) {
        wf_sn_injector_free(inj);
        return st;
    }
    *out = inj;
    return WF_OK;
}

void wf_sn_injector_free(wf_sn_injector *inj)
{
    if (!inj) return;
    for (int f = 0; f < WF_NFILTER; f++) {
        if (inj->slots[f])
            for (size_t i = 0; i < inj->sample.n; i++) wf_salt_lc_free(inj->slots[f][i].lc);
        free(inj->slots[f]);
        free(inj->bp[f]);
    }
    wf_skyindex_free(inj->index);
    wf_salt_free(inj->model);
    wf_sn_sample_free(&inj->sample);
    free(inj);
}

static wf_status band(wf_sn_injector *inj, wf_filter f)
{
    if (inj->bp[f]) return WF_OK;
    if (!(inj->bp[f] = malloc(sizeof *inj->bp[f])) || !(inj->slots[f] = calloc(inj->sample.n, sizeof *inj->slots[f]))) {
        free(inj->bp[f]);
        inj->bp[f] = NULL;
        return wf_error(WF_ERR_NOMEM, "SN injector: out of memory");
    }
    wf_status st = wf_bandpass_load(f, inj->data_dir, inj->bp[f]);
    if (st) {
        free(inj->bp[f]);
        inj->bp[f] = NULL;
        free(inj->slots[f]);
        inj->slots[f] = NULL;
    }
    return st;
}

wf_status wf_sn_injector_select(wf_sn_injector *inj, const char *filter, double mjd,
                                const wf_skyregion *reg, wf_scene_sn **out, size_t *n)
{
    *out = NULL;
    *n = 0;
    if (!inj->index) return WF_OK;
    wf_selection sel = {0};
    wf_status st = wf_skyindex_select(inj->index, reg, &sel);
    if (st || !sel.n) {
        wf_skyindex_selection_free(&sel);
        return st;
    }
    wf_filter f;
    if ((st = wf_filter_parse(filter, &f)) || (st = band(inj, f))) {
        wf_skyindex_selection_free(&sel);
        return st;
    }
    wf_scene_sn *v = calloc(sel.n, sizeof *v);
    if (!v) {
        wf_skyindex_selection_free(&sel);
        return wf_error(WF_ERR_NOMEM, "SN injector: out of memory");
    }
    const wf_sn_sample *s = &inj->sample;
    size_t k = 0;
    for (size_t j = 0; j < sel.n && !st; j++) {
        size_t i = sel.idx[j];
        wf_scene_sn *sn = &v[k];
        sn->id = s->id[i];
        sn->host_id = s->host_id[i];
        sn->ra = s->ra[i];
        sn->dec = s->dec[i];
        sn->z = s->z[i];
        sn->phase = (mjd - s->t0[i]) / (1.0 + s->z[i]);
        sn->mag = 99.0;
        sn->flags = 0;
        if (sn->phase < inj->phase_min || sn->phase > inj->phase_max) {
            sn->flags = WF_SALT_OUT_PHASE; /* no light: in the truth, not drawn, no model work */
            k++;
            continue;
        }
        lc_slot *slot = &inj->slots[f][i];
        if (!slot->lc) {
            wf_salt_params p = {s->z[i], s->t0[i], s->x0[i], s->x1[i], s->c[i]};
            if ((st = wf_salt_lc_init(inj->model, &p, inj->bp[f], WF_SALT_INTERP_BICUBIC, &slot->lc))) break;
        }
        double rate;
        unsigned flags;
        if ((st = wf_salt_lc_rate(slot->lc, mjd, &rate, &flags))) break;
        sn->flags = flags;
        if (rate > 0) {
            st = wf_bandpass_mag_ab(inj->bp[f], rate, &sn->mag);
            /* the light curve's slope at mid-exposure, central difference over +-0.01 d (the
             * template is smooth on that scale: its grid is 1 rest-frame day) */
            const double h = 0.01;
            double rm, rp;
            unsigned fm, fp;
            if (!st) st = wf_salt_lc_rate(slot->lc, mjd - h, &rm, &fm);
            if (!st) st = wf_salt_lc_rate(slot->lc, mjd + h, &rp, &fp);
            if (!st && !(fm | fp)) sn->dlnf_dt = (rp - rm) / (2.0 * h * 86400.0) / rate;
        }
        k++;
    }
    wf_skyindex_selection_free(&sel);
    if (st) {
        free(v);
        return st;
    }
    *out = v;
    *n = k;
    return WF_OK;
}

const char *wf_sn_injector_sample_path(const wf_sn_injector *inj) { return inj->sample_path; }

const char *wf_sn_injector_model_dir(const wf_sn_injector *inj) { return inj->model_dir; }
