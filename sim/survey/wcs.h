/* Focal plane and world coordinates of the 18 WFI SCAs.
 *
 * The geometry is GalSim's `galsim.roman.getWCS` (design 20210204): every SCA has a centre
 * (u0, v0) in the focal-plane frame, measured from the boresight, and a polynomial from its
 * pixels to that frame whose linear part is the pixel matrix and whose higher terms GalSim
 * writes as SIP A/B coefficients. For a pointing (RA, Dec of the boresight, observatory
 * position angle PA) the SCA gets a TAN-SIP WCS built the way GalSim builds it, so pixel
 * positions agree with GalSim's to a few thousandths of a pixel (tests/test_wcs.c).
 *
 * Conventions (docs/SURVEY.md has the derivation):
 *  - PA is GalSim's `PA` argument: the position angle, east of north, of the observatory +Y
 *    axis at the boresight. The focal-plane axes are at PA + theta_fpa (120 deg).
 *  - Pixel coordinates in this C API are 0-based: (0, 0) is the centre of the first pixel,
 *    the SCA spans [-0.5, 4087.5] on each axis. FITS and GalSim number the same pixel
 *    (1, 1); add 1 to go to them. CRPIX in wf_wcs and in the header is FITS (1-based).
 *  - RA and Dec are ICRS degrees.
 */
#ifndef WF_WCS_H
#define WF_WCS_H

#include <fitsio.h>
#include "hal/status.h"

#define WF_WCS_NSCA 18
#define WF_WCS_NPIX 4088      /* active pixels per axis */
#define WF_WCS_SIP_N 5        /* coefficient arrays are N x N: order <= 4 */
#define WF_WCS_SOURCE_MAX 1100

typedef struct wf_focal_plane {
    char source[WF_WCS_SOURCE_MAX]; /* "built-in" or the data directory read */
    double theta_fpa_deg;           /* focal-plane axes relative to observatory +Y [120] */
    int sip_order;                  /* highest i+j of the non-linear terms (0: linear model) */
    /* Per SCA (index sca-1): centre in the focal-plane frame, degrees, in GalSim's sky
     * convention (+u towards decreasing RA when the frame is unrotated, +v north). */
    double u0[WF_WCS_NSCA], v0[WF_WCS_NSCA];
    /* Pixel -> focal-plane polynomial: a[s][i][j] multiplies x^i y^j (x, y from CRPIX).
     * The linear terms are in deg/pixel; the others are used as SIP A/B (pixel units). */
    double a[WF_WCS_NSCA][WF_WCS_SIP_N][WF_WCS_SIP_N];
    double b[WF_WCS_NSCA][WF_WCS_SIP_N][WF_WCS_SIP_N];
} wf_focal_plane;

typedef struct wf_wcs {
    int sca;                        /* 1..18 */
    int nx, ny;                     /* pixels per axis (4088) */
    double crpix[2];                /* FITS 1-based reference pixel (2044, 2044) */
    double crval[2];                /* RA, Dec of the reference pixel, degrees */
    double cd[2][2];                /* degrees per pixel: (RA---TAN, DEC--TAN) x (x, y) */
    double pa_sca_deg;              /* position angle of the pixel +y axis (ORIENTAT) */
    int a_order;                    /* SIP order (0: none) */
    double a[WF_WCS_SIP_N][WF_WCS_SIP_N], b[WF_WCS_SIP_N][WF_WCS_SIP_N];
} wf_wcs;

/* The built-in focal plane: GalSim's 20210204 SCA centres and the linear part of each SCA's
 * pixel polynomial, without the non-linear terms (sip_order 0). Against the full model its
 * positions differ by at most 0.015 pixel (docs/SURVEY.md, tests/test_wcs.c). */
void wf_wcs_focal_plane_builtin(wf_focal_plane *fp);

/* Reads DIR/roman/sca_positions_20210204.txt and DIR/roman/sip_20210204.txt (GalSim's
 * share/roman files). A missing file is WF_ERR_IO; a malformed, duplicated or missing row is
 * WF_ERR_INPUT naming the file and line. fp is untouched on error. */
wf_status wf_wcs_focal_plane_load(const char *data_dir, wf_focal_plane *fp);

/* data_dir NULL or "": the built-in focal plane; otherwise wf_wcs_focal_plane_load. */
wf_status wf_wcs_focal_plane(const char *data_dir, wf_focal_plane *fp);

/* The TAN-SIP WCS of SCA `sca` (1..18) for a boresight at (ra, dec) and observatory position
 * angle pa, all degrees, as galsim.roman.getWCS(world_pos, PA=pa) builds it. |dec| must be
 * below 90 (the position angle is undefined at a pole). */
wf_status wf_wcs_for_sca(const wf_focal_plane *fp, double ra, double dec, double pa, int sca,
                         wf_wcs *out);

/* 0-based pixel -> RA, Dec (degrees, RA in [0, 360)). */
wf_status wf_wcs_pix2world(const wf_wcs *w, double x, double y, double *ra, double *dec);

/* RA, Dec -> 0-based pixel, inverting the SIP polynomial by Newton's method to 1e-9 pixel.
 * A position more than 90 degrees from CRVAL, or where the iteration does not converge (far
 * outside the SCA), is WF_ERR_RANGE. Positions off the SCA are returned, not refused. */
wf_status wf_wcs_world2pix(const wf_wcs *w, double ra, double dec, double *x, double *y);

/* Inverse SIP (AP/BP) of order ap_order (<= 4) fitted by least squares to the exact inverse on
 * a grid over the SCA; *max_resid (may be NULL) is the largest pixel error of the fit there. */
wf_status wf_wcs_fit_inverse(const wf_wcs *w, int ap_order, double ap[WF_WCS_SIP_N][WF_WCS_SIP_N],
                             double bp[WF_WCS_SIP_N][WF_WCS_SIP_N], double *max_resid);

/* Writes the WCS into the current HDU of f: WCSAXES, CTYPE (RA---TAN-SIP / DEC--TAN-SIP, or
 * RA---TAN / DEC--TAN without SIP), CUNIT, CRPIX, CRVAL, CD, LONPOLE, RADESYS, A/B_ORDER and
 * A_i_j/B_i_j, AP/BP_ORDER and AP_i_j/BP_i_j (fitted here), ORIENTAT and SCA_NUM (sca > 0 only). `path`
 * names the file in messages. */
wf_status wf_wcs_write_header(const wf_wcs *w, fitsfile *f, const char *path);

/* Reads the WCS of the current image HDU of f (NAXISn, CTYPE RA---TAN[-SIP]/DEC--TAN[-SIP],
 * CRPIX, CRVAL, CD, A/B_ORDER and A_i_j/B_i_j; SCA_NUM and ORIENTAT when present): the
 * headers wf_wcs_write_header writes and products carry. No WCS, another projection or a
 * singular CD is WF_ERR_INPUT naming the file and HDU. */
wf_status wf_wcs_read_header(fitsfile *f, const char *path, wf_wcs *out);

/* The gnomonic (TAN) projection about the tangent point (ra0, dec0), every argument in radians
 * (the units the WCS computes in: converting on the way would move its results by an ulp):
 * xi points east and eta north on the plane touching the unit sphere there, so hypot(xi, eta)
 * is the tangent of the distance from (ra0, dec0). The projection of every WCS here and of the
 * survey's coverage grid. project: WF_ERR_RANGE for a point 90 deg or more from the tangent
 * point (xi, eta untouched). deproject: RA is ra0 plus the offset, not wrapped into [0, 2 pi). */
wf_status wf_wcs_tangent_project(double ra0, double dec0, double ra, double dec, double *xi,
                                 double *eta);
void wf_wcs_tangent_deproject(double ra0, double dec0, double xi, double eta, double *ra,
                              double *dec);

/* Angular distance between two positions, degrees. */
double wf_wcs_separation(double ra1, double dec1, double ra2, double dec2);

#endif
