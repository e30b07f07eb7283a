#include "hal/scene.h"
#include "hal/file.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Fraction of a unit Gaussian (centre c, sigma s) falling in the pixel [i - 0.5, i + 0.5]. */
static double pixel_fraction(int i, double c, double s)
{
    double k = 1.0 / (M_SQRT2 * s);
    return 0.5 * (erf((i + 0.5 - c) * k) - erf((i - 0.5 - c) * k));
}

static double grid_centre(const wf_scene_grid *g, int i) { return g->spacing / 2 + i * g->spacing; }

static wf_status grid_fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    const wf_scene_grid *g = ctx;
    int reach = (int)ceil(8.0 * g->sigma) + 1;
    int nsx = g->spacing > 0 ? (g->ncols - g->spacing / 2 + g->spacing - 1) / g->spacing : 0;
    int nsy = g->spacing > 0 ? (g->nrows - g->spacing / 2 + g->spacing - 1) / g->spacing : 0;
    for (int y = y0; y < y1; y++) {
        float *row = rate + (size_t)(y - y0) * ncols;
        /* accumulate in double: a bright source on a faint sky loses digits in float */
        double acc[ncols > 0 ? ncols : 1];
        for (int x = 0; x < ncols; x++) acc[x] = g->sky;
        for (int j = 0; j < nsy && g->flux != 0.0; j++) {
            double cy = grid_centre(g, j);
            if (fabs(y - cy) > reach) continue;
            double fy = g->flux * pixel_fraction(y, cy, g->sigma);
            for (int i = 0; i < nsx; i++) {
                double cx = grid_centre(g, i);
                int xa = (int)floor(cx) - reach, xb = (int)ceil(cx) + reach;
                if (xa < 0) xa = 0;
                if (xb > ncols - 1) xb = ncols - 1;
                for (int x = xa; x <= xb; x++) acc[x] += fy * pixel_fraction(x, cx, g->sigma);
            }
        }
        for (int x = 0; x < ncols; x++) row[x] = (float)acc[x];
    }
    return WF_OK;
}

wf_status wf_scene_grid_source(wf_scene_grid *grid, wf_scene_source *out)
{
    if (grid->ncols < 1 || grid->nrows < 1 || grid->spacing < 1 || !(grid->sigma > 0.0) ||
        !isfinite(grid->sky) || !isfinite(grid->flux))
        return wf_error(WF_ERR_RANGE, "grid scene: bad parameters (spacing %d, sigma %g)",
                        grid->spacing, grid->sigma);
    out->ctx = grid;
    out->fill_rate = grid_fill;
    out->rows_empty = NULL;
    out->fill_slope = NULL;
    return WF_OK;
}

double wf_scene_grid_total(const wf_scene_grid *g)
{
    int nsx = (g->ncols - g->spacing / 2 + g->spacing - 1) / g->spacing;
    int nsy = (g->nrows - g->spacing / 2 + g->spacing - 1) / g->spacing;
    double k = 1.0 / (M_SQRT2 * g->sigma), total = g->sky * g->ncols * (double)g->nrows;
    for (int j = 0; j < nsy; j++) {
        double cy = grid_centre(g, j);
        double fy = 0.5 * (erf((g->nrows - 0.5 - cy) * k) - erf((-0.5 - cy) * k));
        for (int i = 0; i < nsx; i++) {
            double cx = grid_centre(g, i);
            total += g->flux * fy * 0.5 * (erf((g->ncols - 0.5 - cx) * k) - erf((-0.5 - cx) * k));
        }
    }
    return total;
}

/* ---- replay ---------------------------------------------------------------------------- */

#define REPLAY_MAGIC "WFRATE1\n"
#define REPLAY_HEADER 16

static wf_status replay_fill(void *ctx, int y0, int y1, int ncols, float *rate)
{
    wf_scene_replay *rp = ctx;
    if (ncols != rp->ncols || y0 < 0 || y1 > rp->nrows || y1 < y0)
        return wf_error(WF_ERR_INPUT, "%s: asked for rows %d-%d x %d columns, file has %d x %d",
                        rp->path, y0, y1, ncols, rp->nrows, rp->ncols);
    long off = REPLAY_HEADER + (long)y0 * ncols * 4;
    if (fseek(rp->file, off, SEEK_SET) != 0)
        return wf_error(WF_ERR_IO, "%s: cannot seek to row %d", rp->path, y0);
    size_t n = (size_t)(y1 - y0) * ncols;
    unsigned char b[4];
    for (size_t i = 0; i < n; i++) {
        if (fread(b, 1, 4, rp->file) != 4)
            return wf_error(WF_ERR_IO, "%s: truncated at row %d", rp->path, y0 + (int)(i / ncols));
        uint32_t u = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
        memcpy(&rate[i], &u, 4);
    }
    return WF_OK;
}

wf_status wf_scene_replay_open(wf_scene_replay *rp, const char *path, wf_scene_source *out)
{
    memset(rp, 0, sizeof *rp);
    rp->path = path;
    rp->file = fopen(path, "rb");
    if (!rp->file) return wf_error(WF_ERR_IO, "%s: cannot open replay file", path);
    unsigned char h[REPLAY_HEADER];
    if (fread(h, 1, sizeof h, rp->file) != sizeof h || memcmp(h, REPLAY_MAGIC, 8) != 0) {
        fclose(rp->file);
        rp->file = NULL;
        return wf_error(WF_ERR_INPUT, "%s: not a wfisim rate recording (bad header)", path);
    }
    rp->ncols = (int)((uint32_t)h[8] | (uint32_t)h[9] << 8 | (uint32_t)h[10] << 16 | (uint32_t)h[11] << 24);
    rp->nrows = (int)((uint32_t)h[12] | (uint32_t)h[13] << 8 | (uint32_t)h[14] << 16 | (uint32_t)h[15] << 24);
    if (rp->ncols < 1 || rp->nrows < 1) {
        fclose(rp->file);
        rp->file = NULL;
        return wf_error(WF_ERR_INPUT, "%s: bad shape %d x %d", path, rp->ncols, rp->nrows);
    }
    out->ctx = rp;
    out->fill_rate = replay_fill;
    out->rows_empty = NULL;
    out->fill_slope = NULL;
    return WF_OK;
}

void wf_scene_replay_close(wf_scene_replay *rp)
{
    if (rp->file) fclose(rp->file);
    rp->file = NULL;
}

wf_status wf_scene_record(const wf_scene_source *src, int ncols, int nrows, int tile_rows,
                          float *scratch, const char *path)
{
    char tmp[4096];
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    FILE *f = fopen(tmp, "wb");
    if (!f) return wf_error(WF_ERR_IO, "%s: cannot create", tmp);
    unsigned char h[REPLAY_HEADER];
    memcpy(h, REPLAY_MAGIC, 8);
    for (int i = 0; i < 4; i++) {
        h[8 + i] = (unsigned char)((uint32_t)ncols >> (8 * i));
        h[12 + i] = (unsigned char)((uint32_t)nrows >> (8 * i));
    }
    wf_status st = WF_OK;
    if (fwrite(h, 1, sizeof h, f) != sizeof h) st = wf_error(WF_ERR_IO, "%s: write failed", tmp);
    for (int y0 = 0; y0 < nrows && !st; y0 += tile_rows) {
        int y1 = y0 + tile_rows < nrows ? y0 + tile_rows : nrows;
        if ((st = wf_scene_fill(src, y0, y1, ncols, scratch))) break;
        size_t n = (size_t)(y1 - y0) * ncols;
        for (size_t i = 0; i < n && !st; i++) {
            uint32_t u;
            memcpy(&u, &scratch[i], 4);
            unsigned char b[4] = {(unsigned char)u, (unsigned char)(u >> 8), (unsigned char)(u >> 16),
                                  (unsigned char)(u >> 24)};
            if (fwrite(b, 1, 4, f) != 4) st = wf_error(WF_ERR_IO, "%s: write failed (disk full?)", tmp);
        }
    }
    if (fclose(f) != 0 && !st) st = wf_error(WF_ERR_IO, "%s: close failed (disk full?)", tmp);
    if (!st) st = wf_file_rename(tmp, path);
    if (st) remove(tmp);
    return st;
}
