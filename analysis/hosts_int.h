/* Internals shared by analysis/hosts.c (reading, association) and analysis/hostsout.c (the
 * files written). Not part of the public interface. */
#ifndef WF_HOSTS_INT_H
#define WF_HOSTS_INT_H

#include <fitsio.h>
#include <stddef.h>

#include "analysis/hosts.h"
#include "sim/survey/wcs.h"

/* Outcomes of one method for one SN. */
enum { HOSTS_CORRECT, HOSTS_WRONG, HOSTS_UNDETECTED, HOSTS_OUTSIDE, HOSTS_HOSTLESS_NONE, HOSTS_HOSTLESS_CHOSEN };

typedef struct hosts_image {
    const char *path;
    int nx, ny;
    wf_wcs wcs;
    double scale_min, scale_max;  /* arcsec per pixel, the CD matrix's singular values */
    double ra_c, dec_c, radius_deg; /* a circle holding the image */
    fitsfile *wht;                /* a coadd's WHT HDU, or NULL */
} hosts_image;

/* A truth row; x, y its FITS pixel in the image. z and host only for SNe. */
typedef struct hosts_obj {
    long long id;
    double ra, dec, x, y, z;
    long long host;
} hosts_obj;

typedef struct hosts_objv {
    hosts_obj *v;
    size_t n, cap, unique;
} hosts_objv;

typedef struct hosts_det {
    long long id;
    double x, y, ra, dec, a, b, theta;
    double cov[3];  /* the ellipse on the sky, arcsec^2 (east-east, east-north, north-north) */
    double amax;    /* its semi-major axis, arcsec */
    int has_dlr;    /* A, B > 0 */
    long gal;       /* index of the truth galaxy matched to it, -1 */
    int excluded;   /* 1: matched to a star, 2: to a SN (not a candidate host) */
} hosts_det;

typedef struct hosts_grid {
    int nx, ny;
    size_t *start, *idx;
} hosts_grid;

typedef struct hosts_line {
    hosts_image im;
    hosts_det *det;
    size_t ndet;
    hosts_objv gal, star, sne;
    long *gal_det;  /* detection matched to each galaxy, -1 */
    long sne_rows;  /* SNE rows read, anywhere */
    hosts_grid grid;
} hosts_line;

/* One SN's result. *_det are detection indices in the line, *_det_id the catalog IDs. */
typedef struct hosts_row {
    long long sn, host, dlr_gal, near_gal, host_det_id, dlr_det_id, near_det_id;
    double z, ra, dec, edge;
    int line;
    long host_det, dlr_det, near_det;
    double host_sep, host_ddlr, dlr_sep, dlr_ddlr, near_sep, near_ddlr;
    int dlr_out, near_out;
} hosts_row;

typedef struct hosts_rows {
    hosts_row *v;
    size_t n, cap;
} hosts_rows;

wf_status hosts_rows_push(hosts_rows *rows, const hosts_row *r);
/* Keeps one row per SN, counts, and writes the four files into out_dir. */
wf_status hosts_finish(hosts_rows *rows, const wf_hosts_options *o, wf_hosts_summary *sum, const char *out_dir);

#endif
