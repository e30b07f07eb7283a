/* SNANA HOSTLIB (sim/sn/hostlib.c): the input as a host library, with its weight map. */
#include "fuzz/common.h"
#include "sim/sn/hostlib.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fz_write("hosts.HOSTLIB", data, size, path);
    wf_catalog cat;
    wf_hostlib_info info;
    if (wf_hostlib_read(path, &cat, &info) == WF_OK) {
        wf_catalog_free(&cat);
        wf_hostlib_info_free(&info);
    }
    return 0;
}
