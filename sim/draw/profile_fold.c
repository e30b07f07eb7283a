/* The fold: the object's transform sampled on the fine grid k = (u, v) dk, times the phases
 * that place it, times PSF x pixel read off the PSF's tables, added into the FFT box's bins
 * (u mod M, v mod M); and, where the largest box is too small for an object, its periodic
 * images' light taken out of the stamp again. */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/trig.h"

/* wf_profile_phase_lines (sim/draw/profile_int.h). The step's and the anchors' sines and cosines
 * are taken together in SIMD lanes (sim/numeric/trig.h): one at a time through libm they were ~1.3 M
 * calls over GalSim's scene, most of them two or three per knot. */
#define PHASE_ANGLES 512
void wf_profile_phase_lines(int n, const double *theta, int lo, int hi, double *re0, size_t line,
                            size_t imoff, size_t st, int alt)
{
    const int nb = (hi - lo) / 32 + 1, per = 1 + nb; /* angles per line: the step, the anchors */
    if (per > PHASE_ANGLES) { /* lines longer than the buffer in pieces: the same anchors */
        const int span = 32 * (PHASE_ANGLES - 1);
        for (int l = lo; l <= hi; l += span)
            wf_profile_phase_lines(n, theta, l, hi - l >= span ? l + span - 1 : hi, re0 + (size_t)(l - lo) * st,
                                   line, imoff, st, alt);
        return;
    }
    const int chunk = PHASE_ANGLES / per;
    double ang[PHASE_ANGLES], cs[PHASE_ANGLES], sn[PHASE_ANGLES];
    for (int j0 = 0; j0 < n; j0 += chunk) {
        const int m = n - j0 < chunk ? n - j0 : chunk;
        for (int j = 0; j < m; j++) {
            double th = theta[j0 + j];
            ang[j * per] = th;
            for (int b = 0; b < nb; b++) {
                int u0 = lo + 32 * b;
                ang[j * per + 1 + b] = -u0 * th;
            }
        }
        wf_trig_sincos(ang, m * per, cs, sn);
        for (int j = 0; j < m; j++) {
            double *re = re0 + (size_t)(j0 + j) * line, *im = re + imoff;
            double sr = cs[j * per], si = sn[j * per]; /* step e^{-i theta}, times -1 with alt */
            if (alt) sr = -sr;
            else si = -si;
            for (int b = 0; b < nb; b++) {
                int u0 = lo + 32 * b;
                double sg = alt && (u0 & 1) ? -1.0 : 1.0;
                double cr = sg * cs[j * per + 1 + b], ci = sg * sn[j * per + 1 + b];
                int u1 = u0 + 32 <= hi ? u0 + 32 : hi + 1;
                for (int u = u0; u < u1; u++) {
                    re[(size_t)(u - lo) * st] = cr;
                    im[(size_t)(u - lo) * st] = ci;
                    double nr = cr * sr - ci * si;
                    ci = cr * si + ci * sr;
                    cr = nr;
                }
            }
        }
    }
}

/* bins += run x PSF read off the table by bicubic interpolation: the table's 4 rows around
 * this v collapsed first (into pint, room for cap columns re and im), then 4 taps along u;
 * in pieces when the run spans more table columns than pint holds (same values). */
static void psf_interp(const wf_profile_psf *psf, const int *tix, const double *twx, int tiy,
                       const double *twy, int ua, int n, double *pint, int cap,
                       const double *runr, const double *runi, double *bins)
{
    const size_t side = 2 * (size_t)psf->kr + 1;
    for (int i0 = 0; i0 < n;) {
        int i1 = n; /* this piece: i0 .. i1 - 1 */
        while (tix[ua + i1 - 1] + 3 - tix[ua + i0] + 1 > cap) i1 = i0 + (i1 - i0 + 1) / 2;
        int t0 = tix[ua + i0], t1 = tix[ua + i1 - 1] + 3;
        double *cr = pint - t0, *ci = pint + cap - t0;
        for (int tt = t0; tt <= t1; tt++) {
            double sr = 0.0, si = 0.0;
            for (int b = 0; b < 4; b++) {
                size_t at = (size_t)(tiy + b) * side + (size_t)tt;
                sr += twy[b] * psf->re[at];
                si += twy[b] * psf->im[at];
            }
            cr[tt] = sr;
            ci[tt] = si;
        }
        for (int i = i0; i < i1; i++) {
            int u = ua + i;
            const double *wu = twx + 4 * (ptrdiff_t)u;
            const double *pr = cr + tix[u], *pi = ci + tix[u];
            double fr = 0.0, fi = 0.0;
            for (int c = 0; c < 4; c++) {
                fr += wu[c] * pr[c];
                fi += wu[c] * pi[c];
            }
            double rr = runr[i], ri = runi[i];
            bins[2 * i] += rr * fr - ri * fi;
            bins[2 * i + 1] += rr * fi + ri * fr;
        }
        i0 = i1;
    }
}

/* One pass over the fine grid: rows v, alias runs of u whose bins lie in the half plane.
 * The run buffer receives the object's transform (times phases) for u in [ua, ub]; it is
 * then multiplied by PSF x pixel and added into the bins. The pass adds knots knot0 ..
 * knot0 + nkb - 1, whose phase lines are in w->kx and w->ky (gd->ks entries per line, real
 * parts then imaginary); the smooth part or point source, and the knot lattice, ride with
 * knot0 <= 0 (and are alone when nkb = 0). */
void wf_profile_fold_pass(wf_profile_work *w, const wf_draw_job *jb, const wf_profile_psf *psf,
                          const wf_draw_grid *gd, int us, int knot0, int nkb)
{
    const wf_fold_kernels *fk = &wf_profile_fold_k;
    const int m = gd->m, half = gd->half, u_all = gd->u;
    const double dk = gd->dk;
    const double *ey = w->ey;
    double *runr = w->run, *runi = w->run + (half + 8);
    /* the PSF read by interpolation: the rest of the run buffer */
    double *pint = w->run + 2 * (size_t)(half + 8);
    const int pcap = wf_profile_ladder_max(w) / 2 + 8 + (wf_profile_ladder_max(w) / 2 - half);
    const size_t row_len = (size_t)m + 2; /* doubles per row of the in-place buffer */
    const size_t ks = gd->ks;
    /* the table this side reads exactly (draw_job: at its period, or its copy at the step) */
    const float *tre = gd->tre, *tim = gd->tim;
    const int tkr = gd->tkr, tst = gd->st;
    const int side = psf ? 2 * tkr + 1 : 0;
    const int smooth = knot0 <= 0;
    double ckr[WF_PROFILE_MAX_KNOTS], cki[WF_PROFILE_MAX_KNOTS];
    wf_knot_lattice *lat = knot0 <= 0 ? gd->lat : NULL;
    const int knots = nkb > 0 || lat;
    double wy[WF_LAT_WMAX];
    wf_smooth_par sp = {.qa = jb->shape.qxx * dk * dk,
                     .re2 = jb->re * jb->re,
                     .r02 = jb->r0 * jb->r0,
                     .fb = jb->fb,
                     .fd = jb->fd,
                     .fpoint = jb->fpoint,
                     .bulge = jb->fb > 0.0,
                     .disk = jb->fd > 0.0,
                     .t = w->sersic,
                     .exr = w->ex + u_all,
                     .exi = w->ex + w->cap_line + u_all};

    for (int v = -u_all; v <= u_all; v++) {
        int umax = gd->rim[abs(v)];
        int us_max = abs(v) <= us ? (int)floor(sqrt((double)us * us - (double)v * v)) : -1;
        if (!knots && us_max < 0) continue;
        const double *lr[WF_LAT_WMAX], *li[WF_LAT_WMAX];
        if (lat) { /* the w coarse rows this row interpolates, and their weights */
            int tv = wf_floor_div(v, lat->r), m0 = tv - lat->w / 2 + 1;
            for (; lat->next <= m0 + lat->w - 1; lat->next++)
                wf_profile_lat_row(fk, lat, lat->next, m);
            const double *wt = lat->wt[v - tv * lat->r];
            const double sg = (v & 1) ? -1.0 : 1.0;
            for (int i = 0; i < lat->w; i++) {
                int slot = (((m0 + i) % lat->w) + lat->w) % lat->w;
                lr[i] = lat->ar + (size_t)slot * lat->al + lat->U;
                li[i] = lat->ai + (size_t)slot * lat->al + lat->U;
                wy[i] = sg * wt[i];
            }
        }
        int by = ((v % m) + m) % m;
        double *crow = w->fft + (size_t)by * row_len;
        double ky = v * dk;
        sp.qb = 2.0 * jb->shape.qxy * dk * ky;
        sp.qc = jb->shape.qyy * ky * ky;
        sp.eyr = ey[2 * (v + u_all)];
        sp.eyi = ey[2 * (v + u_all) + 1];
        for (int j = 0; j < nkb; j++) { /* knot's y phase times its flux */
            const double *kyj = w->ky + (size_t)j * 2 * ks + (size_t)(v + u_all);
            ckr[j] = jb->fknot * kyj[0];
            cki[j] = jb->fknot * kyj[ks];
        }
        const float *er = NULL, *ei = NULL;
        const int *tix = NULL;
        const double *twx = NULL, *twy = NULL;
        int tiy = 0;
        if (gd->mode == WF_GRID_EXACT) {
            size_t off = (size_t)(v * tst + tkr) * side + (size_t)tkr;
            er = tre + off;
            ei = tim + off;
        } else if (gd->mode == WF_GRID_INTERP) {
            tix = w->ix + u_all;
            twx = w->wx + 4 * (size_t)u_all;
            tiy = w->iy[v + u_all];
            twy = w->wy + 4 * (size_t)(v + u_all);
        }
        /* the u range this row needs: all of the band with knots, else the smooth disk */
        int ulim = knots ? umax : us_max;
        int a0 = wf_floor_div(-ulim, m), a1 = wf_floor_div(ulim, m);
        for (int a = a0; a <= a1; a++) {
            int ua = a * m > -ulim ? a * m : -ulim;
            int ub = a * m + half < ulim ? a * m + half : ulim;
            if (ua > ub) continue;
            int n = ub - ua + 1;
            /* the object's transform, times the centring and sub-pixel phases */
            int sa = ua, sb = ua - 1;
            if (smooth) {
                sa = ua > -us_max ? ua : -us_max;
                sb = ub < us_max ? ub : us_max;
            }
            if (sa > ua || sb < ub) {
                memset(runr, 0, (size_t)n * sizeof(double));
                memset(runi, 0, (size_t)n * sizeof(double));
            }
            if (sa <= sb) fk->smooth(&sp, sa, sb - sa + 1, runr + (sa - ua), runi + (sa - ua));
            if (nkb > 0) /* rounded up to whole vectors: the lines and the run have room */
                wf_profile_knot_sum((n + 7) & ~7, nkb, ckr, cki, w->kx + (size_t)(ua + u_all), ks,
                                    runr, runi);
            if (lat) fk->latadd(n, lat->w, wy, lr, li, ua, runr, runi);
            /* times PSF x pixel, into the bins */
            double *bins = crow + 2 * (size_t)(ua - a * m);
            if (gd->mode == WF_GRID_EXACT) {
                fk->psfmul(n, er + (ptrdiff_t)ua * tst, ei + (ptrdiff_t)ua * tst, (size_t)tst, runr,
                           runi, bins);
            } else {
                psf_interp(psf, tix, twx, tiy, twy, ua, n, pint, pcap, runr, runi, bins);
            }
        }
    }
}

#define DEWRAP_NODES 32
#define DEWRAP_MAX_IMAGES 64

/* When the light beyond the largest FFT box exceeds folding_threshold (a galaxy much
 * larger than the PSF: half-light radii of tens of arcsec), the box's periodic images wrap
 * into the stamp. Their light is smooth there (it comes from >= half a box away), so it is
 * computed from the analytic profile, PSF and pixel neglected (relative effect ~(PSF size /
 * galaxy size)^2), on a lattice of DEWRAP_NODES + 1 nodes per side of the FFT box,
 * interpolated bilinearly, and subtracted. The lattice belongs to the box, not to the
 * stamp asked for, so pieces of a stamp get the same pixels. */
wf_status wf_profile_dewrap(const wf_profile_work *w, const wf_draw_job *jb, const wf_draw_grid *gd,
                            double x, double y, wf_stamp *stamp, int box_only)
{
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale, period = gd->m * p;
    double rfar = jb->shape.smax * wf_profile_galaxy_radius(jb, t, 1e-7, NULL);
    int nimg = (int)ceil(rfar / period);
    if (nimg < 1) nimg = 1;
    if (nimg > DEWRAP_MAX_IMAGES)
        return wf_error(WF_ERR_RANGE, "profile: object of radius %.0f arcsec wraps %d times "
                        "around the largest FFT box (%.0f arcsec); raise max_fft", rfar, nimg,
                        period);
    const double h = (double)gd->m / DEWRAP_NODES; /* pixels between nodes */
    const long bx = (long)gd->ic - gd->half, by = (long)gd->jc - gd->half; /* node 0 */
    int a0 = (int)floor((stamp->x0 - bx) / h), a1 = (int)floor((stamp->x0 + stamp->nx - 1 - bx) / h) + 1;
    int b0 = (int)floor((stamp->y0 - by) / h), b1 = (int)floor((stamp->y0 + stamp->ny - 1 - by) / h) + 1;
    if (a0 < 0) a0 = 0;
    if (b0 < 0) b0 = 0;
    if (a1 > DEWRAP_NODES) a1 = DEWRAP_NODES;
    if (b1 > DEWRAP_NODES) b1 = DEWRAP_NODES;
    double node[(DEWRAP_NODES + 1) * (DEWRAP_NODES + 1)];
    for (int b = b0; b <= b1; b++)
        for (int a = a0; a <= a1; a++) {
            double px = (bx + a * h - x) * p, py = (by + b * h - y) * p;
            double wsum = 0.0;
            for (int ny = -nimg; ny <= nimg; ny++)
                for (int nx = -nimg; nx <= nimg; nx++)
                    if (nx || ny)
                        wsum += wf_profile_smooth_density(jb, t, px + nx * period,
                                                          py + ny * period);
            node[b * (DEWRAP_NODES + 1) + a] = wsum * p * p;
        }
    for (int yy = 0; yy < stamp->ny; yy++) {
        /* with a split PSF the stamp reaches beyond the box, where nothing wrapped in */
        if (box_only && (stamp->y0 + yy < by || stamp->y0 + yy >= by + gd->m)) continue;
        double fy = (stamp->y0 + yy - by) / h;
        int b = (int)floor(fy);
        if (b < b0) b = b0;
        if (b > b1 - 1) b = b1 - 1 >= b0 ? b1 - 1 : b0;
        double ty = fy - b;
        for (int xx = 0; xx < stamp->nx; xx++) {
            if (box_only && (stamp->x0 + xx < bx || stamp->x0 + xx >= bx + gd->m)) continue;
            double fx = (stamp->x0 + xx - bx) / h;
            int a = (int)floor(fx);
            if (a < a0) a = a0;
            if (a > a1 - 1) a = a1 - 1 >= a0 ? a1 - 1 : a0;
            double tx = fx - a;
            const double *n0 = node + b * (DEWRAP_NODES + 1) + a;
            int ra = a + 1 <= a1, rb = b + 1 <= b1;
            double v00 = n0[0], v10 = ra ? n0[1] : v00;
            double v01 = rb ? n0[DEWRAP_NODES + 1] : v00;
            double v11 = ra && rb ? n0[DEWRAP_NODES + 2] : (rb ? v01 : v10);
            double wv = (1 - ty) * ((1 - tx) * v00 + tx * v10) + ty * ((1 - tx) * v01 + tx * v11);
            stamp->pix[(size_t)yy * stamp->nx + xx] -= wv;
        }
    }
    return WF_OK;
}
