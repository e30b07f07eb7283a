/* FITS catalogs (sim/survey/catalog.c): the input as a galaxy and as a star catalog file, read by
 * cfitsio through the same path as `scene.catalog` / `scene.stars`. */
#include "fuzz/common.h"
#include "sim/survey/catalog.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    if (fz_gzip_claims_too_much(data, size)) return 0;
    fz_write("catalog.fit", data, size, path);
    wf_catalog a;
    if (wf_catalog_read_galaxies(path, &a) == WF_OK) wf_catalog_free(&a);
    if (wf_catalog_read_stars(path, &a) == WF_OK) wf_catalog_free(&a);
    return 0;
}
