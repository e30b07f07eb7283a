/* Supernova host association (`wfisim hosts`, docs/ANALYSIS.md "wfisim hosts"): for every
 * injected SN, the detected galaxy chosen by nearest angular separation and by the smallest
 * directional-light-radius separation d_DLR (Sullivan et al. 2006, Gupta et al. 2016),
 * against the true host (the detection matched one-to-one to the host galaxy's truth
 * position); counts by redshift in CSV, JSON and a PNG.
 *
 * DLR: a detection's isophotal ellipse (A, B in pixels, THETA degrees counter-clockwise from
 * the image +x axis, as `wfisim detect` writes them) is carried onto the sky (east, north,
 * arcsec) through the local Jacobian of the image's WCS at the detection, as a second-moment
 * matrix C; the DLR is the ellipse's radius in the direction u of the SN, 1/sqrt(u' C^-1 u),
 * which for a conformal WCS of scale s is a·b·s / sqrt((a sin phi)^2 + (b cos phi)^2), phi the
 * angle between the major axis and the SN. d_DLR = separation / DLR. */
#ifndef WF_HOSTS_H
#define WF_HOSTS_H

#include "hal/status.h"
#include "sim/survey/wcs.h"

typedef struct wf_hosts_options {
    double radius;   /* truth matching radius, arcsec [0.3] */
    double dlr_max;  /* largest d_DLR of a chosen host [4, Gupta et al. 2016] */
    double sep_max;  /* largest separation of a host chosen by nearest, arcsec [5] */
    double zbin;     /* redshift bin width [0.25] */
    int quiet;       /* no summary line on stderr */
} wf_hosts_options;

/* Counts over every line (docs/ANALYSIS.md defines each JSON key). An SN in several images
 * counts once, from the image where it is farthest from the edge. */
typedef struct wf_hosts_summary {
    long images, detections, galaxies_matched, excluded; /* excluded: matched to a star or SN */
    long sne;                     /* SNe inside an image's footprint */
    long total;                   /* ... with a true host inside the image */
    long undetected;              /* true host not detected */
    long dlr_correct, dlr_wrong, dlr_none;          /* none: a subset of wrong */
    long nearest_correct, nearest_wrong, nearest_none;
    long host_outside;            /* host's centre off the image (or not in the truth) */
    long hostless, hostless_dlr_chosen, hostless_nearest_chosen;
    long duplicates;              /* SN rows dropped because another image held the SN */
} wf_hosts_summary;

void wf_hosts_defaults(wf_hosts_options *o);

/* The second-moment matrix on the sky (cov[0] = <e e>, cov[1] = <e n>, cov[2] = <n n>,
 * arcsec^2, e east and n north) of the ellipse with semi-axes a, b (pixels) and major axis at
 * theta_deg counter-clockwise from +x, centred on FITS 1-based pixel (x, y) of w. */
wf_status wf_hosts_sky_ellipse(const wf_wcs *w, double x, double y, double a, double b, double theta_deg,
                               double cov[3]);

/* The ellipse's radius (arcsec) in the direction (east, north) (any length > 0; NAN when 0). */
double wf_hosts_dlr(const double cov[3], double east, double north);

/* Reads LIST ("IMAGE DETCAT TRUTH[,TRUTH...]" lines), associates, and writes DIR/hosts.csv,
 * DIR/hosts_by_z.csv, DIR/hosts_summary.json and DIR/hosts.png (each through a temporary
 * file; all are renamed only once every one is whole). Bad input (a missing file, an image
 * without WCS, a catalog without A/B/THETA, truth files without SNe) is WF_ERR_INPUT or
 * WF_ERR_IO naming the file and LIST line, and nothing is written. sum may be NULL. */
wf_status wf_hosts_run(const char *list_path, const char *out_dir, const wf_hosts_options *o,
                       wf_hosts_summary *sum);

/* argv holds what follows "hosts". Returns 0 done, 1 failure (I/O, memory), 2 bad usage or input. */
int wf_cmd_hosts(int argc, char **argv);

#endif
