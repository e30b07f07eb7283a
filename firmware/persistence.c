#include "firmware/persistence.h"

#include <math.h>
#include <string.h>

#include "hal/size.h"

#define NCODES 65536

void wf_persist_defaults(wf_persist_config *cfg)
{
    memset(cfg, 0, sizeof *cfg);
    cfg->model = (wf_persist_model){.A = 0.017, .x0 = 6.0e4, .dx = 5.0e4, .alpha = 0.045,
                                    .gamma = 1.0, .half_well = 5.0e4};
}

/* GalSim's Fermi form at t = 1000 s, where (t/1000)^-r is 1. */
static double fermi(const wf_persist_model *m, double x)
{
    return m->A * pow(x / m->x0, m->alpha) / (exp(-(x - m->x0) / m->dx) + 1.0);
}

/* GalSim's fermi_linear: the Fermi form above the half well, linear to zero below it. */
double wf_persist_level(const wf_persist_model *m, double x)
{
    if (!(x > 0.0)) return 0.0;
    if (x > m->half_well) return fermi(m, x);
    return fermi(m, m->half_well) * x / m->half_well;
}

double wf_persist_time_integral(double gamma, double s1, double s2)
{
    if (gamma == 1.0) return 1000.0 * log(s2 / s1);
    return 1000.0 * (pow(s2 / 1000.0, 1.0 - gamma) - pow(s1 / 1000.0, 1.0 - gamma)) / (1.0 - gamma);
}

int wf_persist_active(const wf_persist_config *cfg)
{
    return cfg->on && cfg->source.depth > 0 && cfg->source.fill;
}

size_t wf_persist_arena_need(const wf_persist_config *cfg, int ncols, int tile_rows)
{
    if (!wf_persist_active(cfg)) return 0;
    size_t halo = wf_size_mul((size_t)tile_rows + 2, (size_t)ncols);
    size_t n = wf_arena_cost(NCODES * sizeof(double));
    n = wf_size_add(n, wf_arena_cost(wf_size_mul3(halo, (size_t)cfg->source.depth, sizeof(uint16_t))));
    return wf_size_add(n, wf_arena_cost(wf_size_mul(halo, sizeof(uint32_t))));
}

wf_status wf_persist_init(wf_persist *p, const wf_persist_config *cfg, const wf_noise *noise,
                          int noisy, int single, int ncols, int tile_rows, wf_arena *arena)
{
    memset(p, 0, sizeof *p);
    p->cfg = *cfg;
    p->noise = *noise;
    p->noisy = noisy;
    p->mode_single = single;
    p->ncols = ncols;
    if (!wf_persist_active(cfg)) return WF_OK;
    const wf_persist_source *s = &cfg->source;
    if (s->depth > WF_PERSIST_DEPTH_MAX)
        return wf_error(WF_ERR_RANGE, "persistence: history of %d exposures (at most %d)", s->depth,
                        WF_PERSIST_DEPTH_MAX);
    const wf_persist_model *m = &cfg->model;
    if (!(m->A >= 0.0 && m->x0 > 0.0 && m->dx > 0.0 && m->half_well > 0.0 && isfinite(m->alpha) &&
          isfinite(m->gamma) && isfinite(m->A)))
        return wf_error(WF_ERR_RANGE, "persistence: model A %g, x0 %g, dx %g, alpha %g, r %g, half well %g "
                        "(A >= 0; x0, dx, half well > 0)", m->A, m->x0, m->dx, m->alpha, m->gamma, m->half_well);
    for (int j = 0; j < s->depth; j++)
        /* up the ramp the current integrates from the reset: at r >= 1 a zero gap diverges */
        if (!(isfinite(s->dt[j]) && (single ? s->dt[j] >= 0.0 : s->dt[j] > 0.0)))
            return wf_error(WF_ERR_RANGE, "persistence: earlier exposure %d ended %g s before this reset "
                            "(must be %s)", j + 1, s->dt[j], single ? ">= 0" : "> 0");
    size_t halo = (size_t)(tile_rows + 2) * (size_t)ncols;
    void *v;
    wf_status st;
    if ((st = wf_arena_reserve(arena, NCODES * sizeof(double), "persistence levels", &v))) return st;
    p->level = v;
    for (int c = 0; c < NCODES; c++) p->level[c] = wf_persist_level(m, c * WF_PERSIST_UNIT);
    if ((st = wf_arena_calloc(arena, halo * (size_t)s->depth, sizeof(uint16_t), "persistence history", &v)))
        return st;
    p->code = v;
    if ((st = wf_arena_calloc(arena, halo, sizeof(uint32_t), "persistence pixels", &v))) return st;
    p->hit = v;
    return WF_OK;
}

wf_status wf_persist_tile(wf_persist *p, int h0, int h1)
{
    p->nhit = 0;
    p->h0 = h0;
    if (!p->code) return WF_OK;
    const wf_persist_source *s = &p->cfg.source;
    wf_status st = s->fill(s->ctx, h0, h1, p->ncols, p->code);
    if (st) return st;
    const int d = s->depth, n = (h1 - h0) * p->ncols;
    for (int i = 0; i < n; i++) {
        const uint16_t *c = p->code + (size_t)i * d;
        int any = 0;
        for (int j = 0; j < d; j++) any |= c[j];
        if (any) p->hit[p->nhit++] = (uint32_t)i;
    }
    return WF_OK;
}

void wf_persist_release(const wf_persist *p, int read, double t1, double t2, uint32_t lo, uint32_t hi,
                        double *charge, double *avg, double weight)
{
    int h = 0, top = p->nhit; /* the first hit at or past lo (the hits are in order) */
    while (h < top) {
        const int mid = h + (top - h) / 2;
        if (p->hit[mid] < lo) h = mid + 1;
        else top = mid;
    }
    if (h == p->nhit || p->hit[h] >= hi) return;
    const wf_persist_source *s = &p->cfg.source;
    const int d = s->depth;
    double span[WF_PERSIST_DEPTH_MAX];
    for (int j = 0; j < d; j++) span[j] = wf_persist_time_integral(p->cfg.model.gamma, s->dt[j] + t1, s->dt[j] + t2);
    const uint32_t px0 = (uint32_t)p->h0 * (uint32_t)p->ncols;
    for (; h < p->nhit && p->hit[h] < hi; h++) {
        uint32_t i = p->hit[h];
        const uint16_t *c = p->code + (size_t)i * d;
        double mean = 0.0;
        for (int j = 0; j < d; j++) mean += p->level[c[j]] * span[j];
        double e = mean;
        if (p->noisy) {
            wf_rng rng;
            wf_rng_init(&rng, &p->noise, px0 + i, (uint32_t)read, WF_PURPOSE_PERSIST);
            e = wf_rng_poisson(&rng, mean);
        }
        charge[i] += e;
        if (avg) avg[i] += weight * e;
    }
}

void wf_persist_single_row(const wf_persist *p, int y, double exptime, double *q)
{
    if (p->nhit == 0) return;
    const wf_persist_source *s = &p->cfg.source;
    const wf_persist_model *m = &p->cfg.model;
    const int d = s->depth;
    double at[WF_PERSIST_DEPTH_MAX]; /* GalSim: the current at the mid-time, for the whole exposure */
    for (int j = 0; j < d; j++) at[j] = pow((s->dt[j] + 0.5 * exptime) / 1000.0, -m->gamma) * exptime;
    const uint32_t lo = (uint32_t)(y - p->h0) * (uint32_t)p->ncols, hi = lo + (uint32_t)p->ncols;
    for (int h = 0; h < p->nhit && p->hit[h] < hi; h++) {
        uint32_t i = p->hit[h];
        if (i < lo) continue;
        const uint16_t *c = p->code + (size_t)i * d;
        for (int j = 0; j < d; j++) q[i - lo] += p->level[c[j]] * at[j];
    }
}

void wf_persist_mark(const wf_persist *p, int y0, int y1, uint8_t *sat, uint8_t mark)
{
    const uint32_t lo = (uint32_t)(y0 - p->h0) * (uint32_t)p->ncols;
    const uint32_t hi = (uint32_t)(y1 - p->h0) * (uint32_t)p->ncols;
    for (int h = 0; h < p->nhit; h++) {
        uint32_t i = p->hit[h];
        if (i >= lo && i < hi && sat[i - lo] == 255) sat[i - lo] = mark;
    }
}
