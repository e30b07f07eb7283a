/* SNANA HOSTLIB reader: a host-galaxy library as a galaxy wf_catalog (SPEC §5 "Hosts";
 * ../shared/data/hosts/Akari_Hosts_subset_SNR_v7.HOSTLIB). docs/SN_HOSTS.md has the full
 * mapping, the conventions and the test results.
 *
 * Format (SNANA sntools_host.c): whitespace-separated text, plain or gzip'd. Lines starting
 * with '#' are comments; a word ending in ':' is a keyword. "VARNAMES:" names the columns of
 * the "GAL:" rows that follow it (one value per name). An optional weight map:
 * "NVAR_WGTMAP: n", "VARNAMES_WGTMAP: v1 .. vn [WGT [SNMAGSHIFT]]" (either or both, on one
 * line or two) and "WGT: x1 .. xn wgt [snmagshift]" rows. A "DOCUMENTATION:" block up to
 * "DOCUMENTATION_END:" and every other keyword are skipped. Column names match
 * case-insensitively; unused columns (pind, logssfr, SPECBASISnn, ...) are ignored.
 *
 * Mapping to the catalog (units: degrees, arcsec, AB magnitudes):
 *   GALID -> id; RA_GAL (or RA_HOST, RA) -> ra; DEC_GAL (DEC_HOST, DEC) -> dec; ZTRUE -> z;
 *   y_obs j_obs h_obs f_obs -> bands Y106 J129 H158 F184 (those present, at least one);
 *   logmass (LOGMASS, LOGMASS_TRUE) and logsfr (LOGSFR, LOGSFR_TRUE) when present.
 *   Sérsic components j = 0, 1 (nj_Sersic, aj_Sersic, bj_Sersic, wj_Sersic; a, b the
 *   half-light semi-axes): the n = 1 component is the disk, the n = 4 one the bulge (the
 *   renderer draws no other index). hlr = sqrt(a b), the circularised radius, because the
 *   renderer's shear preserves area. bulge_frac = w_bulge / (w_disk + w_bulge). A component
 *   of weight 0 takes the other's radius when its own a or b is not positive (the catalog
 *   needs both radii > 0); one absent from the file likewise, with weight 0.
 *   Shape: the catalog has one shape for both components; it is the dominant component's
 *   (larger weight; the disk on a tie): e = (a² − b²)/(a² + b²), e1 = e cos 2β,
 *   e2 = e sin 2β with β = a_rot, pa = 0, knot_frac = 0.
 *   a_rot (SNANA GEN_SNHOST_POS, degrees): SNANA puts a point (a, b) of the ellipse frame at
 *   ΔRA cos δ = a cos(a_rot) + b sin(a_rot), ΔDec = b cos(a_rot) − a sin(a_rot), so the major
 *   axis lies a_rot from east towards south — equivalently a_rot counter-clockwise from +u
 *   (west) towards +v (north) in the renderer's sky frame, which is why β = a_rot. The
 *   position angle east of north is a_rot − 90° (mod 180°).
 *
 * Ranges (as wf_catalog_read_galaxies, docs/CATALOGS.md): ra [−180, 360] (negative wrapped),
 * dec [−90, 90], z [0, 20], magnitudes [−5, 99], logmass [0, 14], logsfr [−20, 5],
 * radii (0, 600] arcsec, weights >= 0 with a positive sum, n exactly 1 or 4, |e| < 1 in
 * single precision.
 *
 * Errors name the file and, for a value, the line and the column:
 *   WF_ERR_IO     cannot open or read
 *   WF_ERR_INPUT  no VARNAMES, missing required column, GAL: before VARNAMES, wrong number
 *                 of values, not a number, NaN or infinity, malformed WGTMAP
 *   WF_ERR_RANGE  a value outside its range, a Sérsic index other than 1 or 4 */
#ifndef WF_HOSTLIB_H
#define WF_HOSTLIB_H

#include <stddef.h>

#include "hal/status.h"
#include "sim/survey/catalog.h"

#define WF_HOSTLIB_MAXWGTVAR 8
#define WF_HOSTLIB_NAMELEN 64

/* The file's weight map as written (SNANA interpolates WGT over it; wfisim computes host
 * weights from logmass and logsfr instead, sim/sn/snhost.h, and keeps the map for checks). */
typedef struct wf_hostlib_wgtmap {
    int nvar;                                       /* grid variables */
    char var[WF_HOSTLIB_MAXWGTVAR][WF_HOSTLIB_NAMELEN];
    size_t n;                                       /* WGT: rows */
    double *x;                                      /* n x nvar, row-major */
    double *wgt;                                    /* n */
    double *snmagshift;                             /* n; 0 when the column is absent */
    int has_snmagshift;
} wf_hostlib_wgtmap;

typedef struct wf_hostlib_info {
    size_t ngal;        /* GAL: rows read */
    int nvarnames;      /* columns named by VARNAMES */
    int has_wgtmap;     /* a WGTMAP block with at least one WGT: row */
    wf_hostlib_wgtmap wgtmap;
    size_t zero_disk;   /* rows whose disk weight is 0 */
    size_t zero_bulge;  /* rows whose bulge weight is 0 */
} wf_hostlib_info;

/* Reads the HOSTLIB at path into *out (a galaxy catalog, initialised here, rows in file
 * order; source = path). info may be NULL; otherwise it is filled and must be released
 * with wf_hostlib_info_free. On error *out and *info are left empty. */
wf_status wf_hostlib_read(const char *path, wf_catalog *out, wf_hostlib_info *info);

void wf_hostlib_info_free(wf_hostlib_info *info);

#endif
