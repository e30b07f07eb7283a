#include "tools/refpix.h"

#include <stdlib.h>
#include <string.h>

#include "firmware/corrnoise.h"

enum { B = WF_CN_BORDER, S = 2 * WF_CN_BORDER };

static uint16_t le16(const unsigned char *p) { return (uint16_t)(p[0] | p[1] << 8); }

wf_status wf_refpix_init(wf_refpix *rp, int nres, int ncols, int nrows, double bias)
{
    memset(rp, 0, sizeof *rp);
    rp->nres = nres;
    rp->ncols = ncols;
    rp->nrows = nrows;
    rp->width = ncols + S;
    rp->nchan = (rp->width + WF_CN_CHANNEL_COLS - 1) / WF_CN_CHANNEL_COLS;
    rp->bias = bias;
    rp->chan = calloc((size_t)nres * (size_t)rp->nchan, sizeof *rp->chan);
    rp->rows = calloc((size_t)nres * S * (size_t)rp->width, sizeof *rp->rows);
    rp->side = calloc((size_t)nres * (size_t)nrows * S, sizeof *rp->side);
    rp->side_in = calloc((size_t)nrows, 1);
    if (!rp->chan || !rp->rows || !rp->side || !rp->side_in) {
        wf_refpix_free(rp);
        return wf_error(WF_ERR_NOMEM, "out of memory for the reference pixels of %d rows", nrows);
    }
    return WF_OK;
}

void wf_refpix_free(wf_refpix *rp)
{
    free(rp->chan);
    free(rp->rows);
    free(rp->side);
    free(rp->side_in);
    memset(rp, 0, sizeof *rp);
}

void wf_refpix_set_rows(wf_refpix *rp, const unsigned char *payload)
{
    const int W = rp->width;
    for (size_t i = 0; i < (size_t)rp->nres * S * (size_t)W; i++) rp->rows[i] = le16(payload + 2 * i);
    for (int r = 0; r < rp->nres; r++)
        for (int c = 0; c < rp->nchan; c++) {
            int X0 = c * WF_CN_CHANNEL_COLS, X1 = X0 + WF_CN_CHANNEL_COLS < W ? X0 + WF_CN_CHANNEL_COLS : W;
            double s = 0.0;
            for (int i = 0; i < S; i++)
                for (int X = X0; X < X1; X++) s += rp->rows[((size_t)r * S + (size_t)i) * W + (size_t)X];
            rp->chan[(size_t)r * rp->nchan + c] = s / (S * (X1 - X0)) - rp->bias;
        }
    rp->have_rows = 1;
}

void wf_refpix_set_cols(wf_refpix *rp, uint32_t y0, uint32_t n, const unsigned char *payload)
{
    for (int r = 0; r < rp->nres; r++)
        for (uint32_t k = 0; k < n; k++)
            for (int i = 0; i < S; i++)
                rp->side[((size_t)r * rp->nrows + y0 + k) * S + (size_t)i] =
                    le16(payload + 2 * (((size_t)r * n + k) * S + (size_t)i));
    memset(rp->side_in + y0, 1, n);
}

int wf_refpix_ready(const wf_refpix *rp, uint32_t y)
{
    return rp->have_rows && y < (uint32_t)rp->nrows && rp->side_in[y];
}

void wf_refpix_correction(const wf_refpix *rp, uint32_t y, double *corr)
{
    const int W = rp->width, nc = rp->ncols;
    for (int r = 0; r < rp->nres; r++) {
        const double *chan = rp->chan + (size_t)r * rp->nchan;
        const uint16_t *side = rp->side + ((size_t)r * rp->nrows + y) * S;
        double mode = 0.0;
        for (int i = 0; i < S; i++) {
            int X = i < B ? i : W - S + i;
            mode += side[i] - rp->bias - chan[X / WF_CN_CHANNEL_COLS];
        }
        mode /= S;
        double *o = corr + (size_t)r * nc;
        for (int x = 0; x < nc; x++) o[x] = chan[(x + B) / WF_CN_CHANNEL_COLS] + mode;
    }
}
