/* The supernova sample: what `wfisim sn generate` writes and the injector, the light-curve
 * command and the truth read. One FITS binary table SNE, one row per SN, columns
 *   ID (int64), Z, T0 (MJD of rest-frame B peak), X0, X1, C, DELTA (coherent intrinsic
 *   scatter, mag, already inside X0), MU (distance modulus), HOSTID (int64, -1 hostless),
 *   RA, DEC (deg), HOSTOFF (arcsec from the host centre), HOSTCOMP (0 disk, 1 bulge, -1 none),
 *   FLAGS (WF_SN_FLAG_*), HOSTA (the host's semi-major axis for isolation, wf_snhost_semimajor,
 *   arcsec; 0 hostless)
 * and the generation's settings as primary-header keywords (docs/SUPERNOVAE.md). Written
 * through a temporary file; the reader checks every value and names file, row and column. */
#ifndef WF_SNCAT_H
#define WF_SNCAT_H

#include <stddef.h>
#include <stdint.h>
#include "hal/status.h"

enum {
    WF_SN_FLAG_HOSTLESS = 1,   /* no galaxy within the redshift tolerance: placed uniformly */
    WF_SN_FLAG_NOHOSTCAT = 2   /* the run asked for hostless SNe (no host catalog) */
};

typedef struct wf_sn_sample {
    size_t n, cap;
    int64_t *id, *host_id;
    double *z, *t0, *x0, *x1, *c, *delta, *mu, *ra, *dec, *host_offset, *host_a;
    int32_t *host_comp, *flags;
    char model[256];   /* the SALT model directory the amplitudes are for */
    char cards[4096];  /* "KEY = value / comment" lines for the primary header */
} wf_sn_sample;

wf_status wf_sn_sample_reserve(wf_sn_sample *s, size_t cap);
/* Appends a zeroed row; *row is its index. */
wf_status wf_sn_sample_push(wf_sn_sample *s, size_t *row);
void wf_sn_sample_free(wf_sn_sample *s);

wf_status wf_sn_sample_write(const wf_sn_sample *s, const char *path);
wf_status wf_sn_sample_read(const char *path, wf_sn_sample *out);

#endif
