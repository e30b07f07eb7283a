/* The split PSF's wing in real space: where flux x wing falls for an object (four phase
 * planes of the oversampled wing table and bilinear weights), added to a stamp or, for the
 * renderer, to a row together with the object's core box, clipped at zero. */
#include <math.h>
#include <stddef.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* Where flux x a phase-plane table (a core's wing, or the core itself for a knot) falls for
 * a point at (x, y): the four phase planes around its fine offset and the bilinear weights
 * (wf_profile_wing_at); the table holds offsets -h .. h + 1 pixels in np samples a row. */
static void table_place(const float *planes, int K, int h, int np, double flux, double x, double y,
                        wf_profile_wing_at *at)
{
    const long plane = (long)np * np;
    /* fine index of pixel i: K (i - x) + K h = K i + s */
    double sx = K * (h - x), sy = K * (h - y);
    double fx0 = floor(sx), fy0 = floor(sy), fx = sx - fx0, fy = sy - fy0;
    long ax = (long)fx0, ay = (long)fy0;
    int a0 = (int)(ax - wf_floor_div_l(ax, K) * K);
    int a1 = (int)(ax + 1 - wf_floor_div_l(ax + 1, K) * K);
    int b0 = (int)(ay - wf_floor_div_l(ay, K) * K);
    int b1 = (int)(ay + 1 - wf_floor_div_l(ay + 1, K) * K);
    *at = (wf_profile_wing_at){
        .wing = planes,
        .np = np,
        .plane = {(b0 * K + a0) * plane, (b0 * K + a1) * plane, (b1 * K + a0) * plane,
                  (b1 * K + a1) * plane},
        .ox = {wf_floor_div_l(ax, K), wf_floor_div_l(ax + 1, K)},
        .oy = {wf_floor_div_l(ay, K), wf_floor_div_l(ay + 1, K)},
        .w = {flux * (1.0 - fy) * (1.0 - fx), flux * (1.0 - fy) * fx, flux * fy * (1.0 - fx),
              flux * fy * fx},
    };
}

static void wing_place(const wf_profile_psf *psf, int core, double flux, double x, double y,
                       wf_profile_wing_at *at)
{
    table_place(psf->core[core - 1].wing, psf->wing_os, psf->wing_half, psf->wing_np, flux, x, y, at);
}

/* stamp += a placed table of half-width h, the rows and columns whose two samples each lie
 * in the table's central 2 lim + 2 (lim <= h: all of it). The fractional position is the same
 * for every pixel, so each row reads four contiguous runs of the phase planes. */
static void table_stamp(const wf_profile_wing_at *at, int h, int lim, wf_stamp *stamp)
{
    const long lo = h - lim, hi = h + lim + 1; /* the samples read */
    long i0 = (long)stamp->x0 > lo - at->ox[0] ? (long)stamp->x0 : lo - at->ox[0];
    long i1 = (long)stamp->x0 + stamp->nx - 1 < hi - at->ox[1] ? (long)stamp->x0 + stamp->nx - 1 : hi - at->ox[1];
    long j0 = (long)stamp->y0 > lo - at->oy[0] ? (long)stamp->y0 : lo - at->oy[0];
    long j1 = (long)stamp->y0 + stamp->ny - 1 < hi - at->oy[1] ? (long)stamp->y0 + stamp->ny - 1 : hi - at->oy[1];
    const long np = at->np;
    if (i0 > i1) return;
    for (long j = j0; j <= j1; j++) {
        long ny0 = j + at->oy[0], ny1 = j + at->oy[1];
        /* rows of the four phase planes from the column of pixel i0 on */
        const float *r00 = at->wing + at->plane[0] + ny0 * np + (i0 + at->ox[0]);
        const float *r01 = at->wing + at->plane[1] + ny0 * np + (i0 + at->ox[1]);
        const float *r10 = at->wing + at->plane[2] + ny1 * np + (i0 + at->ox[0]);
        const float *r11 = at->wing + at->plane[3] + ny1 * np + (i0 + at->ox[1]);
        double *dst = stamp->pix + (size_t)(j - stamp->y0) * stamp->nx + (size_t)(i0 - stamp->x0);
        wf_profile_fold_k.wing(i1 - i0 + 1, at->w[0], at->w[1], at->w[2], at->w[3], r00, r01, r10, r11,
                               dst);
    }
}

void wf_profile_wing_stamp(const wf_profile_psf *psf, int core, double flux, double x, double y,
                           wf_stamp *stamp)
{
    wf_profile_wing_at at;
    wing_place(psf, core, flux, x, y, &at);
    table_stamp(&at, psf->wing_half, psf->wing_half, stamp);
}

void wf_profile_knots_stamp(const wf_profile_psf *psf, int core, int lim, double fknot, int nk,
                            const double *xy, double x, double y, wf_stamp *stamp)
{
    const wf_profile_core *co = &psf->core[core - 1];
    const double p = psf->pixel_scale;
    for (int k = 0; k < nk; k++) {
        wf_profile_wing_at at;
        table_place(co->knot, psf->knot_os, co->knot_half, co->knot_np, fknot, x + xy[2 * k] / p,
                    y + xy[2 * k + 1] / p, &at);
        table_stamp(&at, co->knot_half, lim, stamp);
    }
}

/* The wing for one row j, summed with the box's pixels and clipped, into acc[i - xa] for the
 * columns i in [xa, xb): the columns the wing table covers in one kernel, with or without
 * box pixels, the rest box only. */
static void wing_row(const wf_profile_wing_at *at, int j, int xa, int xb, const float *box,
                     int ca, int cb, double *acc)
{
    const int np = at->np;
    const long ny0 = j + at->oy[0], ny1 = j + at->oy[1];
    if (!box) ca = cb = xa;
    /* the wing's columns: [wa, wb) */
    long i0 = xa > -at->ox[0] ? xa : -at->ox[0];
    long i1 = xb - 1 < np - 1 - at->ox[1] ? xb - 1 : np - 1 - at->ox[1];
    int wa = xa, wb = xa;
    if (i0 <= i1 && ny0 >= 0 && ny1 <= np - 1) wa = (int)i0, wb = (int)i1 + 1;
    if (at->keep_negatives) { /* the box's pixels, then the wing's, as they are */
        for (int i = ca > xa ? ca : xa; i < (cb < xb ? cb : xb); i++) acc[i - xa] += (double)box[i - ca];
        if (wa < wb) {
            const long c = wa;
            wf_profile_fold_k.wing(wb - wa, at->w[0], at->w[1], at->w[2], at->w[3],
                                   at->wing + (at->plane[0] + ny0 * np + at->ox[0] + c),
                                   at->wing + (at->plane[1] + ny0 * np + at->ox[1] + c),
                                   at->wing + (at->plane[2] + ny1 * np + at->ox[0] + c),
                                   at->wing + (at->plane[3] + ny1 * np + at->ox[1] + c),
                                   acc + (wa - xa));
        }
        return;
    }
    wf_profile_box_clipped(box, ca, cb, xa, wa, xa, acc);
    if (wa < wb) {
        /* the four phase planes' entries at column 0 (the columns before wa are never read) */
        const long e[4] = {at->plane[0] + ny0 * np + at->ox[0], at->plane[1] + ny0 * np + at->ox[1],
                           at->plane[2] + ny1 * np + at->ox[0], at->plane[3] + ny1 * np + at->ox[1]};
        int bl = ca > wa ? ca : wa, br = cb < wb ? cb : wb;
        if (bl >= br) bl = br = wb;
        const int cut[4] = {wa, bl, br, wb};
        for (int seg = 0; seg < 3; seg++) {
            int lo = cut[seg], hi = cut[seg + 1];
            if (lo >= hi) continue;
            const float *const r[4] = {at->wing + (e[0] + lo), at->wing + (e[1] + lo),
                                       at->wing + (e[2] + lo), at->wing + (e[3] + lo)};
            wf_profile_fold_k.wingclip(hi - lo, at->w, r, seg == 1 ? box + (lo - ca) : NULL,
                                       acc + (lo - xa));
        }
    }
    wf_profile_box_clipped(box, ca, cb, wb, xb, xa, acc);
}

/* A wing at (x, y) from that core of the PSF; makes sure the kernels are chosen. */
static wf_status check_wing(const wf_profile_psf *psf, int core, double x, double y)
{
    wf_status st = wf_profile_check_position(x, y);
    if (st) return st;
    if (!psf || core < 1 || core > psf->ncore)
        return wf_error(WF_ERR_INPUT, "profile: core %d: a wing needs a PSF split into that many "
                        "cores (it has %d)", core, psf ? psf->ncore : 0);
    (void)wf_profile_simd(-1); /* the kernels, once per process */
    return WF_OK;
}

wf_status wf_profile_add_wing(const wf_profile_psf *psf, int core, double flux, double x,
                              double y, wf_stamp *stamp)
{
    wf_status st = wf_profile_check_stamp(stamp);
    if (st || (st = check_wing(psf, core, x, y))) return st;
    wf_profile_wing_stamp(psf, core, flux, x, y, stamp);
    return WF_OK;
}

wf_status wf_profile_wing_place(const wf_profile_psf *psf, int core, double flux, double x,
                                double y, wf_profile_wing_at *at)
{
    wf_status st = check_wing(psf, core, x, y);
    if (st) return st;
    wing_place(psf, core, flux, x, y, at);
    return WF_OK;
}

wf_status wf_profile_add_wing_row(const wf_profile_wing_at *at, int row, int xa, int xb,
                                  const float *box, int ca, int cb, double *acc)
{
    if (!at->wing || xb < xa || (box && (ca < xa || cb > xb || cb < ca)))
        return wf_error(WF_ERR_INPUT, "profile: wing row columns [%d, %d) with box columns "
                        "[%d, %d) not within them, or no wing placed", xa, xb, ca, cb);
    wing_row(at, row, xa, xb, box, ca, cb, acc);
    return WF_OK;
}
