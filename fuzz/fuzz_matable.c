/* MultiAccum table file (hal/clock.c): the input as `readout.ma_table: FILE`. */
#include "fuzz/common.h"
#include "hal/clock.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    fz_write("table.ma", data, size, path);
    wf_ma_table ma;
    (void)wf_ma_load(path, &ma);
    return 0;
}
