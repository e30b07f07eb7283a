/* Galaxy and star catalogs: in-memory layout, readers (CSV, gzip'd CSV, FITS binary tables,
 * the GalSim benchmark scene) and writers. docs/CATALOGS.md describes every column, alias,
 * range and convention; this header is the API.
 *
 * Layout is one array per column (structure of arrays) so that a 2.7-million-galaxy field
 * costs 80 bytes per galaxy with four bands, and the renderer can take one band's magnitudes
 * as a plain float array. Positions are double (a float RA near 71 deg is only good to
 * ~0.03 arcsec); everything else is float (7 significant digits, far below any catalog's
 * own precision). Rows keep the file's order. */
#ifndef WF_CATALOG_H
#define WF_CATALOG_H

#include <stddef.h>
#include <stdint.h>

#include "hal/status.h"

#define WF_CATALOG_MAXBAND 16
#define WF_CATALOG_BANDLEN 16

typedef enum { WF_CATALOG_GALAXY = 0, WF_CATALOG_STAR = 1 } wf_catalog_kind;

/* Optional galaxy columns, for wf_catalog_init. */
enum {
    WF_CATALOG_HAS_Z = 1,
    WF_CATALOG_HAS_LOGMASS = 2,
    WF_CATALOG_HAS_LOGSFR = 4
};

typedef struct wf_catalog {
    wf_catalog_kind kind;
    size_t n, cap;
    int nband;
    char band[WF_CATALOG_MAXBAND][WF_CATALOG_BANDLEN]; /* "H158" for column mag_H158 */
    char source[256];                                  /* file name, or "synthetic" */

    int64_t *id;
    double *ra, *dec;                  /* degrees; ra in [0, 360) */
    float *mag[WF_CATALOG_MAXBAND];    /* AB magnitude, one array per band */

    /* Galaxies only (NULL for stars). */
    float *hlr_disk;   /* half-light radius of the exponential disk, arcsec (> 0) */
    float *hlr_bulge;  /* half-light radius of the de Vaucouleurs bulge, arcsec (> 0) */
    float *bulge_frac; /* bulge flux / total flux, [0, 1] */
    float *knot_frac;  /* knot flux / disk flux, [0, 0.25] */
    float *e1, *e2;    /* intrinsic distortion (a²-b²)/(a²+b²) components, |e| < 1 */
    float *pa;         /* extra rotation on the sky, degrees (0 when the file has none) */
    float *z;          /* NULL unless has_z */
    float *logmass;    /* log10(stellar mass / Msun), NULL unless has_logmass */
    float *logsfr;     /* log10 SFR/(Msun/yr), NULL unless has_logsfr */
    int has_z, has_logmass, has_logsfr;
} wf_catalog;

/* An empty catalog with the given bands; flags (WF_CATALOG_HAS_*) choose the optional galaxy
 * columns. Rows are added with wf_catalog_push. */
wf_status wf_catalog_init(wf_catalog *cat, wf_catalog_kind kind, int nband,
                          const char *const *bands, int flags, const char *source);

/* Room for at least cap rows. */
wf_status wf_catalog_reserve(wf_catalog *cat, size_t cap);

/* Appends one row (contents undefined until the caller fills every column) and returns its
 * index through *row. */
wf_status wf_catalog_push(wf_catalog *cat, size_t *row);

/* The rows idx[0..n) of src, in that order, as a new catalog (same columns and bands). */
wf_status wf_catalog_subset(const wf_catalog *src, const uint32_t *idx, size_t n,
                            wf_catalog *out);

/* Index of a band by name (case-insensitive, "H158" or "mag_H158"); an error naming the
 * catalog and the bands it has when absent. */
wf_status wf_catalog_band(const wf_catalog *cat, const char *band, int *index);

void wf_catalog_free(wf_catalog *cat);

/* Readers. The format is recognised from the content: a FITS file (plain or gzip'd; the
 * first binary or ASCII table is read) or CSV (plain or gzip'd; header row of column names,
 * '#' comment lines and blank lines skipped). Column names match case-insensitively through
 * the aliases listed in docs/CATALOGS.md; unknown columns are ignored.
 * Errors name the file, the 1-based data row, the column and the value:
 *   WF_ERR_IO     the file cannot be opened or read
 *   WF_ERR_INPUT  missing required column, malformed line (field count, not a number),
 *                 NaN or infinite value, empty field
 *   WF_ERR_RANGE  a value outside the column's range (e.g. dec outside [-90, 90],
 *                 |e| >= 1, knot fraction outside [0, 0.25], size <= 0)
 * On error *out is left empty (freed). */
wf_status wf_catalog_read_galaxies(const char *path, wf_catalog *out);
wf_status wf_catalog_read_stars(const char *path, wf_catalog *out);

/* The GalSim benchmark scene (../shared/reference/galsim/scene_catalog_sca1_pointingA.csv.gz:
 * id, type, ra_deg, dec_deg, mag_<band>, hlr_disk_arcsec, hlr_bulge_arcsec, bulge_frac,
 * knot_frac_of_disk, knot_seed, e1, e2, x_sca1, y_sca1). Rows of type "gal" go to *gal
 * (pa = 0, no z/mass/SFR), "star" to *stars, "sn" to *sne (point sources, star layout). */
wf_status wf_catalog_read_galsim_scene(const char *path, wf_catalog *gal, wf_catalog *stars,
                                       wf_catalog *sne);

/* Which reader takes a file, from its column names alone (the CSV header row, or the FITS
 * table's TTYPEn; the rows are not read): a GalSim benchmark scene (a type column and the
 * scene's columns), a galaxy catalog or a star catalog, preferred in that order among the
 * formats in `accept` (an OR of WF_CATALOG_FORMAT_*). A file that fits none of them is
 * WF_ERR_INPUT naming the columns found and, for each format, the columns it lacks and the
 * scene.kind or key that reads it. */
typedef enum {
    WF_CATALOG_FORMAT_GALAXIES = 1,
    WF_CATALOG_FORMAT_STARS = 2,
    WF_CATALOG_FORMAT_SCENE = 4
} wf_catalog_format;
wf_status wf_catalog_sniff(const char *path, int accept, wf_catalog_format *out);

/* Writers with the canonical column names, so that the readers take the files back
 * exactly (CSV prints doubles with 17 and floats with 9 significant digits). The file is
 * written to path.tmp and renamed, so a failure never leaves a partial catalog. */
wf_status wf_catalog_write_csv(const char *path, const wf_catalog *cat);
wf_status wf_catalog_write_fits(const char *path, const wf_catalog *cat);

#endif
