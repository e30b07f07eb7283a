#include "firmware/cosmic.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>

#include "hal/size.h"

#define DEDX_MIN 10.0
#define DEDX_MAX 10000.0

double wf_cosmic_expected_hits(const wf_detector *det, int ncols, int nrows, double exptime)
{
    double cm = det->pixel_um * 1e-4;
    return det->cr_rate * (ncols * cm) * (nrows * cm) * exptime;
}

static int reach_rows(const wf_detector *det)
{
    /* a track longer than the largest SCA (65536 rows, firmware/readout.c) reaches no further */
    double rows = ceil(det->cr_lmax_um / det->pixel_um) + 2.0;
    return rows < 65538.0 ? (int)rows : 65538;
}

/* Mean pixels a track touches, from the mean path length of the power law: sizes buffers. */
static double mean_pixels_per_hit(const wf_detector *det)
{
    double s = det->cr_slope, a = det->cr_lmin_um, b = det->cr_lmax_um;
    double mean_len = (s + 1.0) / (s + 2.0) * (pow(b, s + 2.0) - pow(a, s + 2.0)) /
                      (pow(b, s + 1.0) - pow(a, s + 1.0));
    return 2.0 + 1.5 * mean_len / det->pixel_um;
}

/* Hits and deposits one tile's buffers hold at most: an int count each. */
#define CR_CAPACITY_MAX ((size_t)INT_MAX)

static wf_status capacities(const wf_detector *det, int ncols, int tile_rows, double exptime,
                            int *cap_dep, int *cap_truth)
{
    /* Hits that can touch a tile start within reach of it; most tracks are short, so the
     * deposits come mostly from hits starting in the tile and a few bands around it. */
    int rows = tile_rows + 2 + 2 * WF_CR_BAND;
    double hits_near = wf_cosmic_expected_hits(det, ncols, rows, exptime);
    double hits_own = wf_cosmic_expected_hits(det, ncols, tile_rows, exptime);
    double dep = hits_near * mean_pixels_per_hit(det);
    /* computed as doubles and checked before they become counts: a long exposure or a high
     * rate must be refused with its reason, not wrap to a negative buffer size */
    size_t cd = wf_size_from_double(2.0 * dep + 12.0 * sqrt(dep + 1.0) + 4.0 * reach_rows(det) * 2 + 256,
                                    CR_CAPACITY_MAX);
    size_t ct = wf_size_from_double(1.5 * hits_own + 12.0 * sqrt(hits_own + 1.0) + 64, CR_CAPACITY_MAX);
    if (cd == WF_SIZE_OVERFLOW || ct == WF_SIZE_OVERFLOW)
        return wf_error(WF_ERR_RANGE,
                        "cosmic rays: %.3g hits expected near a tile of %d x %d pixels in %g s "
                        "(detector.cr_rate %g hits/cm2/s): more than a tile's buffers can count; "
                        "lower the rate, the exposure time or the tile height",
                        hits_near, ncols, tile_rows, exptime, det->cr_rate);
    *cap_dep = (int)cd;
    *cap_truth = (int)ct;
    return WF_OK;
}

wf_status wf_cosmic_arena_need(const wf_detector *det, int ncols, int tile_rows,
                               double exptime, size_t *bytes, size_t *truth_bytes)
{
    int cd, ct;
    wf_status st = capacities(det, ncols, tile_rows, exptime, &cd, &ct);
    if (st) return st;
    *truth_bytes = wf_size_mul((size_t)ct, sizeof(wf_cosmic_record));
    *bytes = wf_size_add(wf_arena_cost(wf_size_mul((size_t)cd, sizeof(wf_cr_deposit))),
                         wf_arena_cost(*truth_bytes));
    return WF_OK;
}

wf_status wf_cosmic_init(wf_cosmic *cr, const wf_detector *det, const wf_noise *noise,
                         int ncols, int nrows, int tile_rows, double exptime, double frame_time,
                         int total_reads, wf_arena *arena)
{
    cr->det = det;
    cr->noise = *noise;
    cr->ncols = ncols;
    cr->nrows = nrows;
    cr->exptime = exptime;
    cr->frame_time = frame_time;
    cr->total_reads = total_reads;
    cr->max_reach_rows = reach_rows(det);
    cr->len_a = pow(det->cr_lmin_um, det->cr_slope + 1.0);
    cr->len_b = pow(det->cr_lmax_um, det->cr_slope + 1.0);
    wf_status st = capacities(det, ncols, tile_rows, exptime, &cr->cap_deposits, &cr->cap_truth);
    if (st) return st;
    cr->ndeposits = cr->ntruth = 0;
    void *p;
    st = wf_arena_calloc(arena, (size_t)cr->cap_deposits, sizeof(wf_cr_deposit),
                         "cosmic-ray deposits", &p);
    if (st) return st;
    cr->deposits = p;
    st = wf_arena_calloc(arena, (size_t)cr->cap_truth, sizeof(wf_cosmic_record),
                         "cosmic-ray truth", &p);
    cr->truth = p;
    return st;
}

/* Inverse CDF of l^s on [lmin, lmax]; its ends' powers come from wf_cosmic_init (a hit is
 * drawn again for every tile it may reach, so per hit they were 2 of 3 pow calls). */
static double sample_length(const wf_cosmic *cr, double u)
{
    const double s1 = cr->det->cr_slope + 1.0, a = cr->len_a, b = cr->len_b;
    return pow(a + u * (b - a), 1.0 / s1);
}

/* Moyal: if g ~ N(0,1) then -ln(g^2) is standard Moyal (exp(-z) is chi-square with one
 * degree of freedom); truncated to romanisim's grid by rejection. */
static double sample_dedx(const wf_detector *det, wf_rng *rng)
{
    for (int tries = 0; tries < 1000; tries++) {
        double g = wf_norm_ppf(wf_rng_uniform53(rng));
        double v = det->cr_dedx_loc - det->cr_dedx_scale * log(g * g);
        if (v >= DEDX_MIN && v <= DEDX_MAX)
            return v;
    }
    return det->cr_dedx_loc;
}

static wf_status add_deposit(wf_cosmic *cr, uint32_t pixel, uint32_t read, double e)
{
    if (cr->ndeposits >= cr->cap_deposits)
        return wf_error(WF_ERR_NOMEM,
                        "cosmic rays: more than %d deposits in one tile (cr_rate %g hits/cm2/s); "
                        "lower the tile height or the rate", cr->cap_deposits, cr->det->cr_rate);
    cr->deposits[cr->ndeposits++] = (wf_cr_deposit){pixel, read, (float)e};
    return WF_OK;
}

static int by_read(const void *a, const void *b)
{
    const wf_cr_deposit *p = a, *q = b;
    if (p->read != q->read) return p->read < q->read ? -1 : 1;
    if (p->pixel != q->pixel) return p->pixel < q->pixel ? -1 : 1;
    return 0;
}

/* Walks the segment through the pixel grid (centres at integers, edges at half-integers)
 * and deposits charge in each pixel by its 3-D chord, keeping rows [h0, h1) only. */
static wf_status trace(wf_cosmic *cr, wf_rng *rng, double x0, double y0, double x1, double y1,
                       double dedx, uint32_t read, int h0, int h1, double *total)
{
    const wf_detector *det = cr->det;
    double dx = x1 - x0, dy = y1 - y0;
    double len = sqrt(dx * dx + dy * dy);
    double depth = det->depth_um / det->pixel_um;
    double e_per_pix = dedx * det->pixel_um / det->cr_ev_per_e; /* mean e- per pixel length */
    int ix = (int)floor(x0 + 0.5), iy = (int)floor(y0 + 0.5);
    int ex = (int)floor(x1 + 0.5), ey = (int)floor(y1 + 0.5);
    int sx = dx > 0 ? 1 : -1, sy = dy > 0 ? 1 : -1;
    double tdx = dx != 0.0 ? fabs(1.0 / dx) : INFINITY, tdy = dy != 0.0 ? fabs(1.0 / dy) : INFINITY;
    double tx = dx != 0.0 ? ((sx > 0 ? ix + 0.5 : ix - 0.5) - x0) / dx : INFINITY;
    double ty = dy != 0.0 ? ((sy > 0 ? iy + 0.5 : iy - 0.5) - y0) / dy : INFINITY;
    double t = 0.0;
    *total = 0.0;
    for (int steps = 0; steps < 8192; steps++) {
        double tn = tx < ty ? tx : ty;
        int last = (ix == ex && iy == ey) || tn >= 1.0;
        if (last) tn = 1.0;
        double chord = (tn - t) * len;
        double l3 = sqrt(depth * depth + chord * chord);
        if (iy >= h0 && iy < h1 && ix >= 0 && ix < cr->ncols && chord > 0.0) {
            double e = wf_rng_poisson(rng, e_per_pix * l3);
            if (e > 0.0) {
                wf_status st = add_deposit(cr, (uint32_t)((iy - h0) * cr->ncols + ix), read, e);
                if (st) return st;
                *total += e;
            }
        } else if (chord > 0.0) {
            /* Draw anyway so the numbers a pixel gets do not depend on which rows a tile keeps. */
            double e = wf_rng_poisson(rng, e_per_pix * l3);
            *total += e;
        }
        if (last) break;
        t = tn;
        if (tx < ty) { ix += sx; tx += tdx; } else { iy += sy; ty += tdy; }
    }
    return WF_OK;
}

wf_status wf_cosmic_tile(wf_cosmic *cr, int h0, int h1, int own0, int own1)
{
    const wf_detector *det = cr->det;
    cr->ndeposits = cr->ntruth = 0;
    int nbands = (cr->nrows + WF_CR_BAND - 1) / WF_CR_BAND;
    int b0 = (h0 - cr->max_reach_rows) / WF_CR_BAND, b1 = (h1 + cr->max_reach_rows) / WF_CR_BAND;
    if (b0 < 0) b0 = 0;
    if (b1 > nbands - 1) b1 = nbands - 1;
    for (int band = b0; band <= b1; band++) {
        int r0 = band * WF_CR_BAND;
        int r1 = r0 + WF_CR_BAND < cr->nrows ? r0 + WF_CR_BAND : cr->nrows;
        wf_rng count_rng;
        wf_rng_init(&count_rng, &cr->noise, (uint32_t)band, 0, WF_PURPOSE_COSMIC);
        double mean = wf_cosmic_expected_hits(det, cr->ncols, r1 - r0, cr->exptime);
        int nhits = (int)wf_rng_poisson(&count_rng, mean);
        for (int i = 0; i < nhits; i++) {
            wf_rng rng;
            wf_rng_init(&rng, &cr->noise, (uint32_t)band, (uint32_t)i + 1u, WF_PURPOSE_COSMIC);
            double x0 = wf_rng_uniform53(&rng) * cr->ncols - 0.5;
            double ys = wf_rng_uniform53(&rng) * (r1 - r0) + r0 - 0.5;
            double phi = 2.0 * M_PI * wf_rng_uniform53(&rng);
            double l = sample_length(cr, wf_rng_uniform53(&rng)) / det->pixel_um;
            double dedx = sample_dedx(det, &rng);
            double ta = wf_rng_uniform53(&rng) * cr->exptime;
            int read = (int)ceil(ta / cr->frame_time) - 1;
            if (read < 0) read = 0;
            if (read >= cr->total_reads) read = cr->total_reads - 1;
            double x1 = x0 + l * cos(phi), ye = ys + l * sin(phi);
            /* romanisim clips the far end to the detector */
            x1 = fmin(fmax(x1, -0.5), cr->ncols - 0.5 - 1e-9);
            ye = fmin(fmax(ye, -0.5), cr->nrows - 0.5 - 1e-9);
            double lo = fmin(ys, ye), hi = fmax(ys, ye);
            int own = ys >= own0 - 0.5 && ys < own1 - 0.5;
            if (!own && (hi < h0 - 0.5 || lo >= h1 - 0.5))
                continue;
            double total;
            wf_status st = trace(cr, &rng, x0, ys, x1, ye, dedx, (uint32_t)read, h0, h1, &total);
            if (st) return st;
            if (own) {
                if (cr->ntruth >= cr->cap_truth)
                    return wf_error(WF_ERR_NOMEM, "cosmic rays: more than %d hits start in one tile",
                                    cr->cap_truth);
                cr->truth[cr->ntruth++] = (wf_cosmic_record){
                    (float)x0, (float)ys, (float)x1, (float)ye, (float)total, (uint32_t)read,
                    (uint32_t)band * 65536u + (uint32_t)i, 0};
            }
        }
    }
    qsort(cr->deposits, (size_t)cr->ndeposits, sizeof *cr->deposits, by_read);
    return WF_OK;
}
