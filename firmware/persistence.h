/* Persistence: charge trapped during earlier exposures of the SCA released into this one.
 * GalSim's Fermi model (galsim.roman fermi_linear, SPEC §2): a pixel that collected x e- in
 * an exposure that ended t seconds ago releases a current (e-/s)
 *   P(x, t) = A (x/x0)^a (t/1000 s)^-r / (exp(-(x - x0)/dx) + 1)   for x > half_well,
 *   P(x, t) = P(half_well, t) x / half_well                         for 0 < x <= half_well.
 * Up the ramp, each read interval [t1, t2] (from the reset) receives Poisson electrons of mean
 * sum_j L(x_j) * integral of (s/1000)^-r over [dt_j + t1, dt_j + t2], in closed form
 * (1000 ln(s2/s1) at r = 1), drawn from the stream (pixel, read, WF_PURPOSE_PERSIST): the same
 * draws per read and direct sampling. Single frame follows GalSim: P at the mid-time
 * (dt_j + T/2) times T, added without noise. Only pixels with a history cost anything. */
#ifndef WF_PERSISTENCE_H
#define WF_PERSISTENCE_H

#include <stddef.h>
#include <stdint.h>
#include "hal/arena.h"
#include "hal/noise.h"
#include "hal/persist.h"

typedef struct wf_persist_model {
    double A;         /* e-/s at t = 1000 s, x = x0 (times the Fermi factor) [0.017] */
    double x0;        /* e- [6e4] */
    double dx;        /* e- [5e4] */
    double alpha;     /* [0.045] */
    double gamma;     /* time power r [1] */
    double half_well; /* e- [5e4]: linear below */
} wf_persist_model;

typedef struct wf_persist_config {
    int on;                     /* and source.depth > 0: otherwise nothing is reserved or run */
    wf_persist_model model;
    wf_persist_source source;
} wf_persist_config;

/* SPEC §2 values (GalSim persistence_fermi_parameters); off, no history. */
void wf_persist_defaults(wf_persist_config *cfg);

/* P(x, 1000 s) in e-/s: the level a stimulus of x e- sets (0 for x <= 0). */
double wf_persist_level(const wf_persist_model *m, double x);

/* Integral of (s / 1000)^-gamma ds over [s1, s2], s in seconds, 0 < s1 <= s2. */
double wf_persist_time_integral(double gamma, double s1, double s2);

/* 1 when the configuration releases anything (on and a history). */
int wf_persist_active(const wf_persist_config *cfg);

typedef struct wf_persist {
    wf_persist_config cfg;
    wf_noise noise;
    int ncols, noisy;
    int mode_single;
    double *level;        /* [65536]: wf_persist_level of each code */
    uint16_t *code;       /* halo block [pixel][depth] */
    uint32_t *hit;        /* halo-block indices of pixels with any code */
    int nhit, h0;
} wf_persist;

/* Arena bytes for a tile of tile_rows rows (+ 2 halo): 0 when not active. */
size_t wf_persist_arena_need(const wf_persist_config *cfg, int ncols, int tile_rows);

/* Checks the history (times > 0 up the ramp, finite) and reserves the buffers. noisy: draw
 * Poisson electrons (else add the means). */
wf_status wf_persist_init(wf_persist *p, const wf_persist_config *cfg, const wf_noise *noise,
                          int noisy, int single, int ncols, int tile_rows, wf_arena *arena);

/* The history of halo rows [h0, h1) from the source. */
wf_status wf_persist_tile(wf_persist *p, int h0, int h1);

/* Up the ramp: the electrons released over [t1, t2] (read `read` ends the interval) added to
 * charge[i] for the pixels lo <= i < hi of the halo block (row-major from its first row), and
 * weight times them to avg[i] when avg is not NULL. */
void wf_persist_release(const wf_persist *p, int read, double t1, double t2, uint32_t lo, uint32_t hi,
                        double *charge, double *avg, double weight);

/* Single frame: GalSim's P(x, dt_j + T/2) T for halo row y's pixels, added to q. */
void wf_persist_single_row(const wf_persist *p, int y, double exptime, double *q);

/* Marks tile rows [y0, y1) whose pixels have a history: sat[x] = mark where it is 255. */
void wf_persist_mark(const wf_persist *p, int y0, int y1, uint8_t *sat, uint8_t mark);

#endif
