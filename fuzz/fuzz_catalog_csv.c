/* Text catalogs (sim/survey/catalog.c): the input as a galaxy catalog, a star catalog and a GalSim
 * benchmark scene, the three CSV readers (plain or gzip'd, recognised from the content). */
#include "fuzz/common.h"
#include "sim/survey/catalog.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fz_write("catalog.csv", data, size, path);
    wf_catalog a, b, c;
    if (wf_catalog_read_galaxies(path, &a) == WF_OK) wf_catalog_free(&a);
    if (wf_catalog_read_stars(path, &a) == WF_OK) wf_catalog_free(&a);
    if (wf_catalog_read_galsim_scene(path, &a, &b, &c) == WF_OK) {
        wf_catalog_free(&a);
        wf_catalog_free(&b);
        wf_catalog_free(&c);
    }
    return 0;
}
