/* Synthetic galaxy and star catalogs for runs without an input catalog. The model (number
 * counts, sizes, redshifts, masses, SFRs, colours, shapes, stars, clustering) and its
 * sources are in docs/CATALOGS.md.
 *
 * The field is cut into square cells in the tangent plane at the field centre (x towards
 * east, y towards north). A cell's objects come only from random streams keyed by
 * (seed, cell, object), WF_PURPOSE_SCENE with the cell index in the pixel word, so any subset
 * of cells generates exactly the objects that generating the whole field would give them,
 * in any order, on any thread. That is what lets a footprint query (wf_synth_select) touch
 * only the cells under one SCA. */
#ifndef WF_SYNTH_H
#define WF_SYNTH_H

#include <stddef.h>
#include <stdint.h>

#include "hal/status.h"
#include "sim/survey/catalog.h"
#include "sim/survey/skyindex.h"

typedef struct wf_synth_config {
    uint64_t seed;
    double ra0, dec0;        /* field centre, degrees (71, -53: Akari Deep Field South) */
    double radius_deg;       /* field radius: cells whose centre lies within it (1.6: 8.0 deg²) */
    double cell_arcmin;      /* cell side in the tangent plane (1) */
    double h_bright, h_faint;/* H158 range of galaxies (15, 26: ~152 per arcmin²) */
    double faint_slope;      /* dex/mag of dN/dm beyond H = 25.5 (0.17) */
    double star_density;     /* stars per arcmin² with star_v_bright <= V <= star_v_faint (2.5) */
    double star_v_bright, star_v_faint; /* (12, 27) */
    int clustering;          /* 0 (default): Poisson positions; 1: Neyman-Scott groups */
    double cluster_fraction; /* fraction of galaxies in groups (0.3) */
    double cluster_members;  /* mean members per group (8) */
    double cluster_sigma_arcsec; /* Gaussian group radius (10); 4 sigma must fit in a cell */
} wf_synth_config;

typedef struct wf_synth wf_synth;

/* The defaults above. */
wf_status wf_synth_defaults(wf_synth_config *cfg);

/* Checks the configuration and precomputes the model tables. */
wf_status wf_synth_create(const wf_synth_config *cfg, wf_synth **out);
void wf_synth_free(wf_synth *s);

/* Bands of the synthetic catalogs: Y106, J129, H158, F184 (AB). */
#define WF_SYNTH_NBAND 4
wf_status wf_synth_bands(const char *const **bands);

/* Every cell of the field, ascending (caller frees *cells). */
wf_status wf_synth_cells(const wf_synth *s, uint32_t **cells, size_t *ncell);

/* The field cells that may hold objects of a region (a superset: cells whose bounding cap
 * meets the region's bounding cap), ascending (caller frees *cells). */
wf_status wf_synth_region_cells(const wf_synth *s, const wf_skyregion *reg, uint32_t **cells,
                                size_t *ncell);

/* The objects of the given cells (in the given order, then by object) as new catalogs in
 * *gal and *stars (either may be NULL to skip that kind; the caller frees them with
 * wf_catalog_free). Cells outside the field are an error. */
wf_status wf_synth_generate(const wf_synth *s, const uint32_t *cells, size_t ncell,
                            wf_catalog *gal, wf_catalog *stars);

/* The objects inside a region (wf_skyindex_contains), generating only the cells it
 * overlaps: the same objects, in the same order, as generating the whole field and keeping
 * those inside, as new catalogs (either pointer may be NULL). */
wf_status wf_synth_select(const wf_synth *s, const wf_skyregion *reg, wf_catalog *gal,
                          wf_catalog *stars);

/* The whole field, as new catalogs (either pointer may be NULL). */
wf_status wf_synth_generate_all(const wf_synth *s, wf_catalog *gal, wf_catalog *stars);

/* Model values, for tests and docs: expected galaxies and stars per arcmin² over the
 * configured magnitude ranges, and the galaxy dN/dH (per arcmin² per mag) at H. */
wf_status wf_synth_expected_density(const wf_synth *s, double *galaxies, double *stars);
wf_status wf_synth_dndm(const wf_synth *s, double h, double *dndm);

/* The solid angle (arcmin²) and the centre (degrees) of a cell. */
wf_status wf_synth_cell_info(const wf_synth *s, uint32_t cell, double *area_arcmin2,
                             double *ra_deg, double *dec_deg);

#endif
