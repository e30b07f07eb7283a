/* Scene source: where the firmware gets the signal falling on the SCA.
 * fill_rate writes the rate in e-/pixel/s for rows [y0, y1) of the active area, row-major,
 * ncols per row. A source must give the same value for a row whatever range it is asked for:
 * neighbouring tiles both ask for the halo rows IPC needs. */
#ifndef WF_SCENE_H
#define WF_SCENE_H

#include <stdint.h>
#include <stdio.h>
#include "hal/status.h"

typedef struct wf_scene_source {
    void *ctx;
    wf_status (*fill_rate)(void *ctx, int y0, int y1, int ncols, float *rate);
    /* Optional; a NULL means "the whole SCA may hold signal". Lets the firmware skip
     * nothing today, kept for renderers that know a tile is empty. */
    int (*rows_empty)(void *ctx, int y0, int y1);
    /* Optional (NULL: the scene is constant in time): sources whose brightness changes over
     * the exposure (supernovae). The rate of a pixel at time t after the reset is
     * rate + slope (t - T/2), T the exposure time, rate as fill_rate gives it for the mid-time;
     * fill_slope writes slope (e-/pixel/s²) for rows [y0, y1), called right after fill_rate
     * for the same rows, and sets *any to 0 when every value is 0 (the firmware then does
     * nothing extra). Over a 900 s exposure a light curve is linear to ~1e-6. */
    wf_status (*fill_slope)(void *ctx, int y0, int y1, int ncols, float *slope, int *any);
} wf_scene_source;

static inline wf_status wf_scene_fill(const wf_scene_source *s, int y0, int y1, int ncols,
                                      float *rate)
{
    return s->fill_rate(s->ctx, y0, y1, ncols, rate);
}

/* Built-in test scene of the main job until the renderer lands: uniform sky plus a square
 * grid of circular Gaussian point sources of known total flux, integrated exactly over each
 * pixel (erf differences), so the flux in the image is known in closed form. */
typedef struct wf_scene_grid {
    int ncols, nrows;
    double sky;        /* e-/pixel/s */
    double flux;       /* e-/s per source, total */
    double sigma;      /* Gaussian sigma, pixels */
    int spacing;       /* pixels between sources; first at spacing/2 */
} wf_scene_grid;

wf_status wf_scene_grid_source(wf_scene_grid *grid, wf_scene_source *out);

/* Sum of the grid scene's rate over the whole SCA, in closed form (for tests). */
double wf_scene_grid_total(const wf_scene_grid *grid);

/* Replay: rate tiles recorded to a file (as by `wfisim record`) feed the firmware, as
 * recorded data would in a hardware-in-the-loop test. File: header "WFRATE1\n", then
 * int32 ncols, nrows, then float32 rows little-endian. Reads only the rows asked for. */
typedef struct wf_scene_replay {
    FILE *file;
    const char *path;
    int ncols, nrows;
} wf_scene_replay;

wf_status wf_scene_replay_open(wf_scene_replay *rp, const char *path, wf_scene_source *out);
void wf_scene_replay_close(wf_scene_replay *rp);

/* Writes a replay file by drawing every row of `src` (tile_rows at a time). */
wf_status wf_scene_record(const wf_scene_source *src, int ncols, int nrows, int tile_rows,
                          float *scratch, const char *path);

#endif
