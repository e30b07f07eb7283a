/* Drawing galaxies and point sources: with a PSF in Fourier space, without one in real
 * space (see sim/draw/profile.h for the method and docs/OPTICS.md "Profiles" for the measured
 * errors and costs). This file holds the objects and the draw that ties the steps together;
 * the steps are in sim/draw/profile_*.c (docs/ARCHITECTURE.md lists them).
 *
 * The image of an object on the pixel grid is the pixel-convolved profile sampled at pixel
 * centres. Its transform is F(k) = G(k) P(k) Pix(k) e^{-i k.d}; sampling at pitch p folds
 * every k into the band |k| < pi / p, and an FFT box of M pixels samples the folded transform
 * at dk = 2 pi / (M p), periodising the image with period M p (light beyond the box wraps in:
 * the folding error). So: evaluate F on the fine grid k = (u, v) dk out to the band limit,
 * add each value into bin (u mod M, v mod M) (only the bins of the half plane FFTW's c2r
 * reads), and one inverse FFT gives the M x M pixel values (sim/draw/profile_fold.c). The
 * box is centred on pixel (ic, jc) nearest the object: the shift by M/2 pixels is the factor
 * (-1)^(u+v). The stamp, the box and the band come from the accuracy knobs
 * (sim/draw/profile_size.c).
 *
 * Knots are point sources: their transform is a sum of phases, separable in u and v. Summed
 * directly (blocks of WF_PROFILE_KNOT_BLOCK per-knot phase lines) it costs a complex
 * multiply-add per knot and sample; the knot lattice (sim/draw/profile_lattice.c) sums them
 * on a coarser grid and interpolates, to ~1e-9 of the peak, which most galaxies take. Without
 * a PSF a knot is a delta function whose pixel integral puts all its light in the pixel
 * holding it (sim/draw/profile_real.c).
 *
 * The per-sample work runs in kernels with scalar and vector versions that give the same
 * bits (sim/draw/profile_kernels.c). */
#include <fftw3.h>
#include <math.h>
#include <string.h>

#include "hal/simd.h"
#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* ------------------------------------------------------------------------ the objects */

wf_status wf_profile_check_position(double x, double y)
{
    if (!(fabs(x) < 1e8 && fabs(y) < 1e8))
        return wf_error(WF_ERR_RANGE, "profile: position (%g, %g) is not a finite pixel "
                        "position within 1e8", x, y);
    return WF_OK;
}

wf_status wf_profile_galaxy_job(wf_profile_work *w, const wf_galaxy *g, wf_draw_job *jb)
{
    memset(jb, 0, sizeof *jb);
    if (!g) return wf_error(WF_ERR_INPUT, "profile: no galaxy given");
    unsigned id = g->id;
    if (!(g->flux >= 0.0 && g->flux < 1e30))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: flux %g not in [0, 1e30)", id,
                        g->flux);
    if (!(g->bulge_frac >= 0.0 && g->bulge_frac <= 1.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: bulge_frac %g outside [0, 1]", id,
                        g->bulge_frac);
    if (g->bulge_frac > 0.0 && !(g->hlr_bulge > 0.0 && g->hlr_bulge <= 3600.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: bulge half-light radius %g arcsec "
                        "outside (0, 3600]", id, g->hlr_bulge);
    if (g->bulge_frac < 1.0 && !(g->hlr_disk > 0.0 && g->hlr_disk <= 3600.0))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: disk half-light radius %g arcsec "
                        "outside (0, 3600]", id, g->hlr_disk);
    if (!(g->knot_frac >= 0.0 && g->knot_frac <= WF_PROFILE_MAX_KNOT_FRAC))
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: knot_frac %g outside [0, %g]", id,
                        g->knot_frac, WF_PROFILE_MAX_KNOT_FRAC);
    if (g->n_knots < 0 || g->n_knots > WF_PROFILE_MAX_KNOTS)
        return wf_error(WF_ERR_RANGE, "profile: galaxy %u: %d knots outside [0, %d]", id,
                        g->n_knots, WF_PROFILE_MAX_KNOTS);
    wf_status st = wf_profile_shape(g->e1, g->e2, g->rotation, &jb->shape);
    if (st) return wf_error(st, "profile: galaxy %u: %s", id, wf_error_message());

    const wf_sersic_table *t = w->sersic;
    jb->flux = g->flux;
    jb->fb = g->flux * g->bulge_frac;
    double disk = g->flux - jb->fb;
    jb->re = g->bulge_frac > 0.0 ? g->hlr_bulge : 0.0;
    jb->r0 = g->bulge_frac < 1.0 ? g->hlr_disk / t->b1 : 0.0;
    if (g->n_knots > 0 && g->knot_frac > 0.0 && disk > 0.0) {
        if ((st = wf_profile_knots(g, w->knot_pos))) return st;
        jb->nk = g->n_knots;
        jb->fk = disk * g->knot_frac;
        jb->fknot = jb->fk / jb->nk;
        const double(*a)[2] = jb->shape.a;
        double r2max = 0.0; /* squares, and one root: hypot only where they overflow */
        for (int j = 0; j < jb->nk; j++) {
            double x = w->knot_pos[2 * j], y = w->knot_pos[2 * j + 1];
            double sx = a[0][0] * x + a[0][1] * y, sy = a[1][0] * x + a[1][1] * y;
            w->knot_pos[2 * j] = sx;
            w->knot_pos[2 * j + 1] = sy;
            double r2 = sx * sx + sy * sy;
            if (r2 > r2max) r2max = r2;
        }
        jb->knot_rmax = sqrt(r2max);
        if (isinf(r2max)) {
            double r = 0.0;
            for (int j = 0; j < jb->nk; j++) r = fmax(r, hypot(w->knot_pos[2 * j], w->knot_pos[2 * j + 1]));
            jb->knot_rmax = r;
        }
        jb->knots = w->knot_pos;
    }
    jb->fd = disk - jb->fk;
    return WF_OK;
}

/* ------------------------------------------------------------------------ the draw */

static void phase_line_to(double theta, int n, double *re, double *im, size_t st)
{
    wf_profile_phase_lines(1, &theta, -n, n, re, 0, (size_t)(im - re), st, 1);
}

/* The same, complex interleaved into out[2 (u + n)]. */
static void phase_line(double theta, int n, double *out)
{
    phase_line_to(theta, n, out, out + 1, 2);
}

/* Catmull-Rom taps for reading the PSF table at fractional index t (table steps). */
static void cubic_taps(double t, int kr, int *first, double *wgt)
{
    double f0 = floor(t), f = t - f0;
    *first = (int)f0 - 1 + kr;
    double f2 = f * f, f3 = f2 * f;
    wgt[0] = 0.5 * (-f3 + 2.0 * f2 - f);
    wgt[1] = 0.5 * (3.0 * f3 - 5.0 * f2 + 2.0);
    wgt[2] = 0.5 * (-3.0 * f3 + 4.0 * f2 + f);
    wgt[3] = 0.5 * (f3 - f2);
}

/* Negatives (ringing and rounding) set to zero, and stamp->sum and ->clipped. Eight partial
 * sums, one per lane, so that the loops run in SIMD lanes without reassociating: a single
 * running sum waits on each add (a split draw's stamp is summed in ~4 cycles a pixel, ~1.5%
 * of the GalSim scene), and about half the far pixels of a faint object are slightly
 * negative, where a branch would mispredict. The sums are diagnostics: their order is free. */
WF_CLONES static void clip_lanes(double *pix, size_t n, int clip, double *sum, double *clipped)
{
    double s[8] = {0.0}, c[8] = {0.0};
    size_t i = 0;
    if (clip) {
#if defined(__GNUC__)
        typedef double cd8 __attribute__((vector_size(64)));
        typedef long long cl8 __attribute__((vector_size(64)));
        const cd8 zero = {0.0};
        cd8 vs = zero, vc = zero;
        for (; i + 8 <= n; i += 8) {
            cd8 v;
            memcpy(&v, pix + i, sizeof v);
            cl8 neg = (cl8)(v < zero);
            cd8 keep = (cd8)((cl8)v & ~neg);
            vc -= (cd8)((cl8)v & neg);
            vs += keep;
            memcpy(pix + i, &keep, sizeof keep);
        }
        memcpy(s, &vs, sizeof vs);
        memcpy(c, &vc, sizeof vc);
#endif
        for (; i < n; i++) {
            double v = pix[i], neg = v < 0.0 ? v : 0.0;
            c[i % 8] -= neg;
            pix[i] = v - neg;
            s[i % 8] += v - neg;
        }
    } else {
        for (; i + 8 <= n; i += 8)
            for (int k = 0; k < 8; k++) s[k] += pix[i + k];
        for (; i < n; i++) s[i % 8] += pix[i];
    }
    *sum = ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
    *clipped = ((c[0] + c[1]) + (c[2] + c[3])) + ((c[4] + c[5]) + (c[6] + c[7]));
}

/* keep_negatives: the renderer clips the sum of every object instead; only the sum here */
static void clip_negatives(wf_stamp *stamp, int keep_negatives)
{
    clip_lanes(stamp->pix, (size_t)stamp->nx * stamp->ny, !keep_negatives, &stamp->sum, &stamp->clipped);
}

/* wing 0 leaves a split draw's wing to the caller (wf_profile_add_wing); plan non-NULL
 * only decides: plan[0] the core taken (0: none, else its index + 1), plan[1] the FFT
 * side; nothing is drawn. */
static wf_status draw_job(wf_profile_work *w, const wf_draw_job *jb, const wf_profile_psf *psf,
                          double x, double y, wf_stamp *stamp, int wing, int *plan)
{
    wf_status st = wf_profile_check_position(x, y);
    if (st) return st;
    if (psf && fabs(psf->pixel_scale - w->acc.pixel_scale) > 1e-12 * w->acc.pixel_scale)
        return wf_error(WF_ERR_INPUT, "profile: PSF prepared for %g arcsec pixels, drawing "
                        "at %g", psf->pixel_scale, w->acc.pixel_scale);
    if (!psf && plan) {
        plan[0] = 0, plan[1] = 0;
        return WF_OK;
    }
    if (!psf) return wf_profile_draw_nopsf(w, jb, x, y, stamp);
    (void)wf_profile_simd(-1); /* the kernels, once per process */
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale;
    wf_draw_grid gd;
    memset(&gd, 0, sizeof gd);
    gd.ic = (int)lround(x);
    gd.jc = (int)lround(y);
    gd.dx = (x - gd.ic) * p;
    gd.dy = (y - gd.jc) * p;
    gd.lat_exp = -log(w->acc.knot_accuracy);

    /* FFT side. The stamp must lie inside the box [ic - M/2, ic + M/2 - 1]; the light
     * beyond the box, which wraps in, must stay below folding_threshold; and the side
     * depends on the object, not on the bounds asked for (unless they reach beyond its own
     * stamp), so that a piece of a stamp has the same pixels as the whole. */
    long hx = (long)gd.ic - stamp->x0, hx1 = (long)stamp->x0 + stamp->nx - gd.ic;
    long hy = (long)gd.jc - stamp->y0, hy1 = (long)stamp->y0 + stamp->ny - gd.jc;
    long need = 2 * (hx > hx1 ? hx : hx1);
    long need_y = 2 * (hy > hy1 ? hy : hy1);
    if (need_y > need) need = need_y;
    if (need > wf_profile_ladder_max(w))
        return wf_error(WF_ERR_RANGE, "profile: stamp %dx%d at (%d, %d) is more than max_fft "
                        "%d / 2 pixels from the object at (%.2f, %.2f)", stamp->nx,
                        stamp->ny, stamp->x0, stamp->y0, wf_profile_ladder_max(w), x, y);
    /* With a split PSF the box of an extended object whose wing error bound is tolerated
     * holds object x core only, whose light ends at the core radius; the stamp's pixels
     * beyond the box get the wing alone. Of the cores it tolerates, the smallest (the
     * smallest box). Other objects take the whole table (a point source would gain nothing:
     * its box is set by the PSF either way). split: the core's index + 1, or 0. */
    wf_profile_psf view;
    int split = 0;
    if (jb->fpoint == 0.0)
        for (int c = psf->ncore; c >= 1 && !split; c--)
            if (2.0 * jb->flux * psf->core[c - 1].wing_max < w->acc.wing_tolerance) split = c;
    if (split) {
        view = *psf;
        view.re = psf->core[split - 1].re;
        view.im = psf->core[split - 1].im;
        view.steps = psf->core[split - 1].steps;
        memcpy(view.alt, psf->core[split - 1].alt, sizeof view.alt);
        view.env = psf->core[split - 1].env;
        psf = &view;
    }
    double rfold = wf_profile_object_radius(jb, t, psf, w->acc.folding_threshold, split);
    double rown =
        split ? 0.0 : wf_profile_object_radius(jb, t, psf, 1.0 - w->acc.flux_fraction, 0);
    double need_fold = 2.0 * ceil(fmax(rfold, rown) / p) + 2.0;
    int mi = wf_profile_choose_size(w, psf, split ? need_fold : fmax((double)need, need_fold));
    gd.m = w->sizes[mi];
    if (plan) {
        plan[0] = split, plan[1] = gd.m;
        return WF_OK;
    }
    if (!wing && !split)
        return wf_error(WF_ERR_INPUT, "profile: a core-only draw of an object that does not take the "
                        "split PSF with these knobs (wf_profile_galaxy_core says which do)");
    int clamped = gd.m < need_fold;
    gd.half = gd.m / 2;
    gd.dk = 2.0 * M_PI / (gd.m * p);

    /* knots: each the core at its position, read from the core's knot table where the
     * reading's error bound is tolerated (the box then holds the smooth light alone, whose
     * transform ends far sooner); else in the box, those inside it (beyond it they would
     * wrap) */
    int klim = -1; /* the knot table read out to klim pixels, the least its bound allows */
    if (split && !clamped && jb->nk > 0 && w->knot_method == WF_KNOTS_AUTO) {
        const wf_profile_core *co = &psf->core[split - 1];
        const double miss = 0.1 * (1.0 - w->acc.flux_fraction);
        for (int l = 0; l <= co->knot_half && klim < 0; l++)
            if (jb->fk * (co->knot_interp + co->knot_out[l]) <= w->acc.wing_tolerance && co->knot_miss[l] <= miss)
                klim = l;
    }
    const int real_knots = klim >= 0;
    w->knot_last[3] = real_knots ? jb->nk : 0;
    w->knot_last[4] = real_knots ? klim : 0;
    double kedge = (gd.half - 1) * p;
    for (int j = 0; j < (real_knots ? 0 : jb->nk); j++) {
        double kx = jb->knots[2 * j] + gd.dx, ky = jb->knots[2 * j + 1] + gd.dy;
        if (fabs(kx) <= kedge && fabs(ky) <= kedge) {
            w->knot_box[2 * gd.nk] = jb->knots[2 * j];
            w->knot_box[2 * gd.nk + 1] = jb->knots[2 * j + 1];
            gd.nk++;
        }
    }
    gd.kpos = w->knot_box;

    /* Fourier extent: the PSF's band (or the no-PSF cap), and the smooth profile's own */
    double kband = fmin(psf->kmax, WF_PSF_BAND_NYQ * M_PI / p);
    const double dkt = 2.0 * M_PI / (psf->table_fft * psf->pixel_scale);
    const double kcs = wf_profile_psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 0);
    const double kck = gd.nk ? wf_profile_psf_kcut(jb, t, psf, w->acc.kvalue_accuracy, 1) : 0.0;
    double ksmooth = fmin(kband, kcs);
    double kknots = gd.nk ? fmin(kband, kck) : 0.0;
    int lim, tab = wf_profile_psf_period(psf, gd.m);
    if (tab >= 0) { /* the table at a period the side divides, or its copy at the step */
        const wf_profile_table *at = tab ? &psf->alt[tab - 1] : NULL;
        const wf_profile_steps *sc = tab ? &at->steps : &psf->steps;
        gd.mode = WF_GRID_EXACT;
        gd.st = (tab ? at->fft : psf->table_fft) / gd.m;
        gd.tre = tab ? at->re : psf->re;
        gd.tim = tab ? at->im : psf->im;
        gd.tkr = tab ? at->kr : psf->kr;
        lim = gd.tkr / gd.st;
        for (int i = 0; i < sc->n && gd.st > 1; i++)
            if (sc->st[i] == gd.st) {
                gd.tre = sc->re[i];
                gd.tim = sc->im[i];
                gd.tkr = sc->kr[i];
                gd.st = 1;
            }
    } else {
        gd.mode = WF_GRID_INTERP;
        lim = (int)floor((psf->kr - 2) * (double)gd.m / psf->table_fft);
    }
    int cap = (w->cap_line - 1) / 2;
    if (lim > cap) lim = cap;
    int us = (int)floor(ksmooth / gd.dk), uk = gd.nk ? (int)floor(kknots / gd.dk) : 0;
    if (us > lim) us = lim;
    if (uk > lim) uk = lim;
    if (w->acc.cut_tolerance > 0.0) { /* half the tolerance each when there are knots */
        double tol = (gd.nk ? 0.5 : 1.0) * w->acc.cut_tolerance;
        /* the floor's search starts at the pointwise cut's ring when kvalue_accuracy <=
         * WF_PROFILE_CUT_KEEP (nothing beyond it is above the floor then) */
        const int above = w->acc.kvalue_accuracy <= WF_PROFILE_CUT_KEEP;
        int js = wf_profile_tail_cut(jb, t, psf, gd.dk, gd.m, us, tol, 0);
        if (js < us) {
            int from = above ? (int)lround(kcs / dkt) : psf->kr;
            double kk = wf_profile_psf_kcut_from(jb, t, psf, WF_PROFILE_CUT_KEEP, 0, from);
            int keep = (int)floor(kk / gd.dk);
            us = js > keep ? js : keep < us ? keep : us;
        }
        if (gd.nk) {
            int jk = wf_profile_tail_cut(jb, t, psf, gd.dk, gd.m, uk, tol, 1);
            if (jk < uk) {
                int from = above ? (int)lround(kck / dkt) : psf->kr;
                double kk = wf_profile_psf_kcut_from(jb, t, psf, WF_PROFILE_CUT_KEEP, 1, from);
                int keep = (int)floor(kk / gd.dk);
                uk = jk > keep ? jk : keep < uk ? keep : uk;
            }
        }
    }
    gd.u = us > uk ? us : uk;
    w->cut_last[0] = us;
    w->cut_last[1] = uk;

    for (int v = 0; v <= gd.u; v++) w->rim[v] = (int)floor(sqrt((double)gd.u * gd.u - (double)v * v));
    gd.rim = w->rim;
    phase_line_to(gd.dk * gd.dx, gd.u, w->ex, w->ex + w->cap_line, 1);
    phase_line(gd.dk * gd.dy, gd.u, w->ey);
    if (gd.mode == WF_GRID_INTERP) {
        double ratio = (double)psf->table_fft / gd.m;
        for (int u = -gd.u; u <= gd.u; u++) {
            cubic_taps(u * ratio, psf->kr, &w->ix[u + gd.u], &w->wx[4 * (u + gd.u)]);
            cubic_taps(u * ratio, psf->kr, &w->iy[u + gd.u], &w->wy[4 * (u + gd.u)]);
        }
    }

    memset(w->fft, 0, (size_t)gd.m * (gd.m + 2) * sizeof(double));
    /* knots: the inner ones on a lattice where that costs less, the outer few (whose extent
     * would make the lattice fine) and all others summed directly */
    wf_knot_lattice lat;
    int nd = gd.nk; /* summed directly: the first nd of knot_box */
    w->knot_last[0] = w->knot_last[1] = 0;
    if (gd.nk && w->knot_method != WF_KNOTS_DIRECT && wf_profile_knot_plan(w, &gd, p, &lat)) {
        nd = gd.nk - lat.nk;
        wf_profile_lat_build(w, jb, &gd, &lat);
        gd.lat = &lat;
        w->knot_last[0] = lat.r;
        w->knot_last[1] = lat.w;
    }
    w->knot_last[2] = nd;
    if (!nd) {
        wf_profile_fold_pass(w, jb, psf, &gd, us, gd.lat ? 0 : -1, 0);
    } else {
        /* as many knots per pass as the phase-line buffers hold (all of them but for the
         * largest boxes): each pass multiplies by the PSF once */
        size_t len = 2 * (size_t)gd.u + 1;
        gd.ks = ((len + 3) & ~(size_t)3) + 8; /* room for wf_profile_knot_sum's rounding up */
        size_t room = (size_t)WF_PROFILE_KNOT_BLOCK * (size_t)w->cap_line / gd.ks;
        int per = room > (size_t)WF_PROFILE_MAX_KNOTS ? WF_PROFILE_MAX_KNOTS : (int)room;
        if (per < 1) per = 1;
        for (int k0 = 0; k0 < nd; k0 += per) {
            int nkb = nd - k0 < per ? nd - k0 : per;
            double thx[WF_PROFILE_MAX_KNOTS], thy[WF_PROFILE_MAX_KNOTS];
            for (int j = 0; j < nkb; j++) {
                const double *kp = gd.kpos + 2 * (size_t)(k0 + j);
                thx[j] = gd.dk * (kp[0] + gd.dx);
                thy[j] = gd.dk * (kp[1] + gd.dy);
            }
            wf_profile_phase_lines(nkb, thx, -gd.u, gd.u, w->kx, 2 * gd.ks, gd.ks, 1, 1);
            wf_profile_phase_lines(nkb, thy, -gd.u, gd.u, w->ky, 2 * gd.ks, gd.ks, 1, 1);
            /* the smooth part and the lattice ride with pass 0 */
            wf_profile_fold_pass(w, jb, psf, &gd, us, k0, nkb);
        }
    }
    wf_status pst = wf_profile_draw_plan(w, mi);
    if (pst) return pst;
    fftw_execute_dft_c2r((fftw_plan)w->plans[mi], (fftw_complex *)w->fft, w->fft);

    const double norm = 1.0 / ((double)gd.m * gd.m);
    /* the box's pixels within the stamp (all of it unless the PSF is split) */
    long bx0 = (long)gd.ic - gd.half, by0 = (long)gd.jc - gd.half;
    long xa = (long)stamp->x0 > bx0 ? (long)stamp->x0 : bx0;
    long xb = (long)stamp->x0 + stamp->nx < bx0 + gd.m ? (long)stamp->x0 + stamp->nx : bx0 + gd.m;
    for (int yy = 0; yy < stamp->ny; yy++) {
        double *dst = stamp->pix + (size_t)yy * stamp->nx;
        long yb = (long)stamp->y0 + yy - by0;
        if (yb < 0 || yb >= gd.m || xa >= xb) {
            memset(dst, 0, (size_t)stamp->nx * sizeof(double));
            continue;
        }
        const double *src = w->fft + (size_t)yb * (gd.m + 2) + (size_t)(xa - bx0);
        for (long xx = stamp->x0; xx < xa; xx++) dst[xx - stamp->x0] = 0.0;
        for (long xx = xa; xx < xb; xx++) dst[xx - stamp->x0] = src[xx - xa] * norm;
        for (long xx = xb; xx < (long)stamp->x0 + stamp->nx; xx++) dst[xx - stamp->x0] = 0.0;
    }
    if (real_knots) wf_profile_knots_stamp(psf, split, klim, jb->fknot, jb->nk, jb->knots, x, y, stamp);
    if (split && wing) wf_profile_wing_stamp(psf, split, jb->flux, x, y, stamp);
    if (clamped && jb->fpoint == 0.0 && (st = wf_profile_dewrap(w, jb, &gd, x, y, stamp, split)))
        return st;
    clip_negatives(stamp, w->keep_negatives);
    stamp->fft = gd.m;
    return WF_OK;
}

wf_status wf_profile_check_stamp(const wf_stamp *stamp)
{
    if (!stamp || !stamp->pix || stamp->nx < 1 || stamp->ny < 1 || stamp->nx > 65536 ||
        stamp->ny > 65536)
        return wf_error(WF_ERR_INPUT, "profile: stamp without pixels or with bounds %dx%d",
                        stamp ? stamp->nx : 0, stamp ? stamp->ny : 0);
    return WF_OK;
}

static void clear_stamp(wf_stamp *stamp)
{
    memset(stamp->pix, 0, (size_t)stamp->nx * stamp->ny * sizeof(double));
    stamp->sum = stamp->clipped = 0.0;
    stamp->fft = 0;
}

/* A galaxy's stamp, its split PSF's wing included or (wing 0) left to the caller. */
static wf_status draw_galaxy(wf_profile_work *work, const wf_galaxy *g, const wf_profile_psf *psf,
                             double x, double y, wf_stamp *stamp, int wing)
{
    wf_status st = wf_profile_check_stamp(stamp);
    if (st) return st;
    wf_draw_job jb;
    if ((st = wf_profile_galaxy_job(work, g, &jb)) || (st = wf_profile_check_position(x, y)))
        return st;
    if (jb.flux == 0.0) {
        clear_stamp(stamp);
        return WF_OK;
    }
    return draw_job(work, &jb, psf, x, y, stamp, wing, NULL);
}

wf_status wf_profile_draw_galaxy(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *stamp)
{
    return draw_galaxy(work, g, psf, x, y, stamp, 1);
}

wf_status wf_profile_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                 const wf_profile_psf *psf, double x, double y,
                                 wf_stamp *bounds, wf_stamp *box, int *core)
{
    if (!g) return wf_error(WF_ERR_INPUT, "profile: no galaxy given");
    wf_draw_job jb;
    wf_galaxy lit = *g;
    if (lit.flux == 0.0) lit.flux = 1.0; /* as wf_profile_galaxy_bounds */
    wf_status st = wf_profile_galaxy_job(work, &lit, &jb);
    if (st || (st = wf_profile_bounds(work, &jb, psf, x, y, bounds, NULL))) return st;
    int plan[2];
    wf_stamp b = *bounds;
    if ((st = draw_job(work, &jb, psf, x, y, &b, 1, plan))) return st;
    *box = *bounds;
    *core = g->flux > 0.0 ? plan[0] : 0;
    if (*core) { /* the FFT box [ic - M/2, ic + M/2) within the bounds */
        long ic = lround(x), jc = lround(y), h = plan[1] / 2;
        long x0 = ic - h > bounds->x0 ? ic - h : bounds->x0;
        long y0 = jc - h > bounds->y0 ? jc - h : bounds->y0;
        long x1 = ic + h < (long)bounds->x0 + bounds->nx ? ic + h : (long)bounds->x0 + bounds->nx;
        long y1 = jc + h < (long)bounds->y0 + bounds->ny ? jc + h : (long)bounds->y0 + bounds->ny;
        box->x0 = (int)x0, box->y0 = (int)y0;
        box->nx = (int)(x1 - x0), box->ny = (int)(y1 - y0);
    }
    return WF_OK;
}

wf_status wf_profile_draw_galaxy_core(wf_profile_work *work, const wf_galaxy *g,
                                      const wf_profile_psf *psf, double x, double y,
                                      wf_stamp *stamp)
{
    return draw_galaxy(work, g, psf, x, y, stamp, 0);
}

wf_status wf_profile_draw_point(wf_profile_work *work, const wf_profile_psf *psf, double flux,
                                double x, double y, wf_stamp *stamp)
{
    wf_status st = wf_profile_check_stamp(stamp);
    if (st || (st = wf_profile_check_position(x, y))) return st;
    if (!(flux >= 0.0 && flux < 1e30))
        return wf_error(WF_ERR_RANGE, "profile: point source flux %g not in [0, 1e30)", flux);
    clear_stamp(stamp);
    if (flux == 0.0) return WF_OK;
    if (!psf) { /* the pixel integral of a delta function */
        long px = lround(x), py = lround(y);
        if (px >= stamp->x0 && px < (long)stamp->x0 + stamp->nx && py >= stamp->y0 &&
            py < (long)stamp->y0 + stamp->ny)
            stamp->pix[(size_t)(py - stamp->y0) * stamp->nx + (size_t)(px - stamp->x0)] = flux;
        stamp->sum = flux;
        return WF_OK;
    }
    wf_draw_job jb;
    memset(&jb, 0, sizeof jb);
    jb.flux = jb.fpoint = flux;
    wf_profile_shape(0.0, 0.0, 0.0, &jb.shape);
    return draw_job(work, &jb, psf, x, y, stamp, 1, NULL);
}
