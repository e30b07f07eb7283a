/* Survey plan (sim/survey/survey.c): the input as the plan.fits that `survey run` and `sn` read.
 * The reader first verifies every HDU's CHECKSUM/DATASUM, which almost no mutation survives,
 * so each input is read twice: as it is, and with its checksums rewritten by cfitsio, so
 * that mutations reach the tables' parsing behind the check. */
#include <fitsio.h>
#include <stdlib.h>

#include "fuzz/common.h"
#include "sim/survey/survey.h"

static void read_plan(const char *path)
{
    wf_survey_row *rows = NULL;
    size_t n = 0;
    if (wf_survey_read_plan(path, &rows, &n) == WF_OK) free(rows);
}

/* 1 when the file opened as FITS and every HDU got fresh checksums. */
static int rewrite_checksums(const char *path)
{
    fitsfile *f;
    int status = 0, nhdu = 0, type;
    if (fits_open_file(&f, path, READWRITE, &status)) return 0;
    fits_get_num_hdus(f, &nhdu, &status);
    for (int i = 1; i <= nhdu && !status; i++) {
        fits_movabs_hdu(f, i, &type, &status);
        fits_write_chksum(f, &status);
    }
    int close = 0;
    fits_close_file(f, &close);
    return !status && !close;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    char path[4096];
    if (fz_gzip_claims_too_much(data, size)) return 0;
    fz_write("plan.fit", data, size, path);
    read_plan(path);
    if (rewrite_checksums(path)) read_plan(path);
    return 0;
}
