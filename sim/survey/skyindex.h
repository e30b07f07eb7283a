/* Sky regions (an SCA footprint as a convex polygon or a circle, grown by a margin) and a
 * spatial index over a catalog's positions, so that the objects of one SCA out of a
 * multi-million-object field are found in milliseconds.
 *
 * The index cuts the sphere into declination bands of fixed height; within a band the
 * objects are sorted by RA. A query visits the bands the region's bounding circle crosses
 * and, in each, only the RA interval the circle can reach there (two intervals across
 * RA = 0/360, all of RA in a band that touches a pole or lies inside the circle), then
 * applies the exact test wf_skyindex_contains to each candidate. Because the exact test is
 * the same function a brute-force scan uses, and the band/RA culling is conservative, the
 * selection equals the scan exactly. Works anywhere on the sphere. */
#ifndef WF_SKYINDEX_H
#define WF_SKYINDEX_H

#include <stddef.h>
#include <stdint.h>

#include "hal/status.h"

#define WF_SKY_MAXVERT 16

/* A prepared region; build it with wf_skyindex_circle or wf_skyindex_polygon. */
typedef struct wf_skyregion {
    int nvert;                       /* 0: circle; otherwise a convex polygon */
    double v[WF_SKY_MAXVERT][3];     /* polygon vertices, unit vectors, counter-clockwise */
    double nrm[WF_SKY_MAXVERT][3];   /* unit normals of the edges v[i] -> v[i+1], inward */
    double centre[3];                /* circle centre, or the polygon's bounding-circle centre */
    double ra_c, dec_c;              /* the same, degrees */
    double radius;                   /* circle radius (rad), without margin */
    double margin;                   /* rad */
    double bound;                    /* bounding-circle radius including the margin (rad) */
    double chord2_circle;            /* circle test: |p - centre|^2 <= this */
    double chord2_bound;             /* quick rejection for polygons */
    double chord2_margin, sin_margin;
} wf_skyregion;

/* The cap within radius_deg + margin_arcsec of (ra, dec). */
wf_status wf_skyindex_circle(double ra_deg, double dec_deg, double radius_deg,
                             double margin_arcsec, wf_skyregion *out);

/* A convex spherical polygon with great-circle edges through n vertices (3..16, either
 * orientation, smaller than a hemisphere), plus every point within margin_arcsec of it,
 * so that objects whose stamps reach onto an SCA from outside are included. Non-convex or
 * degenerate vertex lists are an error. */
wf_status wf_skyindex_polygon(const double *ra_deg, const double *dec_deg, int n,
                              double margin_arcsec, wf_skyregion *out);

/* The exact membership test (1 inside, 0 outside). */
int wf_skyindex_contains(const wf_skyregion *reg, double ra_deg, double dec_deg);

typedef struct wf_skyindex wf_skyindex;

/* Index over n positions (degrees; ra in [0, 360), dec in [-90, 90]; n < 2^32). The arrays
 * are copied (sorted), so the caller may free or reorder them; the index then costs
 * 20 bytes per object. band_arcmin is the declination band height (0: 1 arcmin, suited to
 * SCA-sized queries on fields of ~100+ objects per arcmin²). */
wf_status wf_skyindex_build(const double *ra_deg, const double *dec_deg, size_t n,
                            double band_arcmin, wf_skyindex **out);

void wf_skyindex_free(wf_skyindex *ix);

/* Indices (into the arrays given to wf_skyindex_build) of the objects in a region,
 * ascending. The buffer is reused across queries; free it with wf_skyindex_selection_free.
 * A const index may be queried from several threads, each with its own selection. */
typedef struct wf_selection {
    uint32_t *idx;
    size_t n, cap;
    size_t examined; /* candidates the last query tested exactly (for benchmarks) */
} wf_selection;

wf_status wf_skyindex_select(const wf_skyindex *ix, const wf_skyregion *reg, wf_selection *sel);

void wf_skyindex_selection_free(wf_selection *sel);

#endif
