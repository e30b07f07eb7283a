/* Supernovae of a sample (`wfisim sn generate`) injected into images. For one exposure — a
 * filter, a mid-time and the SCA's footprint on the sky — the injector lists the SNe inside
 * the footprint with the AB magnitude of their light curve at that time. SNe are indexed on
 * the sky once, so an SCA that holds none costs one index lookup and no light-curve work;
 * light curves are built per (SN, filter) on first use and kept. */
#ifndef WF_SNINJECT_H
#define WF_SNINJECT_H

#include <stddef.h>
#include "hal/status.h"
#include "sim/draw/scene.h"
#include "sim/survey/skyindex.h"

typedef struct wf_sn_injector wf_sn_injector;

/* sne_path: the SN table; model_dir: the SALT model it was generated for; data_dir: Roman
 * data ("" for the built-in bandpasses). */
wf_status wf_sn_injector_open(const char *sne_path, const char *model_dir, const char *data_dir,
                              wf_sn_injector **out);
void wf_sn_injector_free(wf_sn_injector *inj);

/* The files it was opened with (their contents go into a product's input digest). */
const char *wf_sn_injector_sample_path(const wf_sn_injector *inj);
const char *wf_sn_injector_model_dir(const wf_sn_injector *inj);

/* The SNe inside reg with their magnitudes in filter at mjd and the light curve's relative
 * slope there (dlnf_dt, for the up-the-ramp reads) (*out malloc'd, *n may be 0).
 * Not thread-safe (light curves are cached): one exposure at a time. */
wf_status wf_sn_injector_select(wf_sn_injector *inj, const char *filter, double mjd,
                                const wf_skyregion *reg, wf_scene_sn **out, size_t *n);

#endif
