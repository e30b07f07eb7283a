/* The index of a folder of survey products: one row per (exposure, SCA) image, with its
 * filter, time, pointing and file names, as FITS (table INDEX) and CSV. Rows are read from the
 * products' own headers, so the index of a run, of a resumed run, or of a folder filled by
 * several runs (job arrays over --exposures ranges) is the same function of the files:
 * `wfisim survey index DIR` rebuilds it from whatever products DIR holds. */
#ifndef WF_SURVEYINDEX_H
#define WF_SURVEYINDEX_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include "hal/status.h"

typedef struct wf_survey_index_row {
    int32_t expid, sca;
    int32_t visit, orient, pointing, pass; /* -1 for a product not made from a plan */
    char filter[8];
    double mjd;                   /* exposure mid-time */
    double ra, dec, pa;           /* boresight and PA (GalSim getWCS) */
    double ra_sca, dec_sca;       /* SCA centre (SCI's CRVAL) */
    double exptime;
    char file[40], truth[48];     /* names within the folder */
    char datasum[24];             /* SCI's DATASUM: which pixels this row describes */
    char digest[72];              /* WFDIGEST: the inputs that made it ("" before digests) */
} wf_survey_index_row;

/* The row of the product dir/file (an image written by the pipeline), from its headers. */
wf_status wf_survey_index_read(const char *dir, const char *file, wf_survey_index_row *row);

/* Sorts rows by (exposure, SCA) and writes dir/survey_index.fits and dir/survey_index.csv,
 * each through a temporary file and a rename. */
wf_status wf_survey_index_write(const char *dir, wf_survey_index_row *rows, size_t n);

/* The rows of every product image in dir (names wfisim_eNNNNNN_scaNN.fits), sorted. */
wf_status wf_survey_index_scan(const char *dir, wf_survey_index_row **rows, size_t *n);


#endif
