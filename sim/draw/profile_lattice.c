/* The knot lattice. The knots' transform K(k) = sum_j f_j e^{-i k.x_j} is needed on the fine
 * grid k = (u, v) dk out to the PSF's band, ~2.2 M^2 samples for an FFT box of M pixels, but
 * the knots lie within a few hlr of the object, a small part of the box: sampled on a lattice r
 * times coarser (period L = M p / r, at least X / rho for knots within X of the object) it is
 * still resolved. With a kernel psi of w taps (spacing Delta = r dk) and Phi its transform,
 * sum_n g(n Delta) psi(k / Delta - n), g the sum over knots of f_j Delta / Phi(x_j)
 * e^{-i n Delta x_j}, equals by Poisson's formula K(k) plus the knots' images at
 * x_j + m L (m != 0) weighted by Phi(x_j + m L) / Phi(x_j): with the Kaiser-Bessel shape
 * (sim/draw/profile_int.h) and beta = pi w (1 - rho) that ratio is ~exp(-pi w sqrt(1 - 2 rho)),
 * exp(-E) with E = -ln(acc.knot_accuracy), times a prefactor of order 10: at the default E = 20
 * the stamps differ from the direct sum's by <= 2e-9 of their peak in tests/test_profile.c,
 * 1e-8 over the GalSim scene (bench/bench_profile.c); a scene lowers E for faint objects
 * (sim/draw/scene.c), down to narrower kernels and coarser lattices. Separable in x and y: g on
 * ~(2 U / r + w)^2 lattice points costs one complex multiply-add per knot (half of them, g
 * being Hermitian); each coarse row is interpolated along u once, each fine sample then takes w
 * real-by-complex multiply-adds from w such rows. Wider kernels allow a larger rho, hence a
 * coarser lattice, for more taps per sample: each draw takes the cheapest
 * (wf_profile_knot_plan), and its coarse rows are interpolated along u as the fold pass
 * (sim/draw/profile_fold.c) reaches them. */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* rho for a kernel of w taps: pi w sqrt(1 - 2 rho) = E (negative: w too narrow for E). */
static double lat_rho(int w, double e)
{
    double a = e / (M_PI * w);
    return 0.5 * (1.0 - a * a);
}

/* Largest |u| any fine row served by coarse row m needs (-1: none). Fine row v takes coarse
 * rows floor(v / r) - w/2 + 1 .. floor(v / r) + w/2. */
static int lat_umax(const wf_knot_lattice *l, int m)
{
    long lo = (long)l->r * (m - l->w / 2), hi = (long)l->r * (m + l->w / 2) - 1;
    long vmin = lo > 0 ? lo : hi < 0 ? -hi : 0;
    return vmin > l->U ? -1 : l->rim[vmin];
}

static int lat_nmax(const wf_knot_lattice *l, int m)
{
    int um = lat_umax(l, m);
    return um < 0 ? -1 : um / l->r + l->w / 2;
}

/* Coarse step for knots within x of the object with a kernel of w taps (0: the lattice
 * would not be coarser than the fine grid). */
static int lat_step(const wf_draw_grid *gd, double p, double x, int w)
{
    double rho = lat_rho(w, gd->lat_exp);
    if (!(rho > 0.0)) return 0;
    double r = x > 0.0 ? floor(rho * gd->m * p / x) : WF_LAT_RMAX;
    if (r > WF_LAT_RMAX) r = WF_LAT_RMAX;
    if (r > gd->u / 2) r = gd->u / 2;
    return r >= 2 ? (int)r : 0;
}

/* Relative costs per operation, measured: a complex multiply-add of the coarse sum, a tap
 * of the fine rows, a tap of the u interpolation. */
#define COST_COARSE 1.0
#define COST_FINE 0.8
#define COST_ROW 1.3

/* Sets the lattice's sizes for step r and w taps; 0 when it does not fit the work's
 * buffers. *c0 + *c1 nk is its cost for nk knots (the direct sum's: nk per fine sample). */
static int lat_size(const wf_profile_work *w, const wf_draw_grid *gd, int r, int wd,
                    wf_knot_lattice *l, double *c0, double *c1)
{
    l->r = r;
    l->w = wd;
    l->rho = lat_rho(wd, gd->lat_exp);
    l->U = gd->u;
    l->rim = gd->rim;
    l->mh = gd->u / r + wd / 2;
    l->nh = lat_nmax(l, 0);
    l->gw = 2 * (size_t)l->nh + 1 + 8;
    if (2 * ((size_t)l->mh + 1) * l->gw > w->cap_lat) return 0;
    size_t ks = ((2 * (size_t)l->nh + 1 + 3) & ~(size_t)3) + 8;
    if ((size_t)l->mh + 1 > ks) return 0; /* the y lines share the x lines' stride */
    size_t ring = 2 * (size_t)wd * (2 * (size_t)l->U + 9) + 2 * (2 * (size_t)l->nh + 1);
    if (ring > 2 * (size_t)WF_LAT_WMAX * ((size_t)w->cap_line / 2 + 9) + (size_t)w->cap_line)
        return 0;
    double coarse = 0.0, rows = 0.0;
    for (int m = 0; m <= l->mh; m++) {
        int up = lat_umax(l, m), un = lat_umax(l, -m);
        if (up >= 0) rows += up + 1.0; /* the half of the u range in alias runs */
        if (m && un >= 0) rows += un + 1.0;
        int um = up > un ? up : un;
        if (um >= 0) coarse += 2.0 * (um / r + wd / 2) + 1.0;
    }
    double fine = 0.5 * M_PI * (double)gd->u * gd->u; /* samples in the alias runs */
    *c0 = wd * (COST_FINE * fine + COST_ROW * rows);
    *c1 = COST_COARSE * coarse;
    return 1;
}

/* Kernel weights, knot weights and the coarse rows m >= 0 of g (the knots' phase lines in
 * w->kx and w->ky, free again afterwards). */
void wf_profile_lat_build(wf_profile_work *w, const wf_draw_job *jb, wf_draw_grid *gd,
                          wf_knot_lattice *l)
{
    const int r = l->r, wd = l->w, nh = l->nh, mh = l->mh;
    const double delta = r * gd->dk;
    l->beta = M_PI * wd * (1.0 - l->rho);
    for (int rho = 0; rho < r; rho++)
        for (int i = 0; i < wd; i++)
            l->wt[rho][i] = wf_knot_kernel((double)rho / r + wd / 2 - 1 - i, wd, l->beta);
    double *gr = w->lat, *gi = w->lat + ((size_t)mh + 1) * l->gw;
    memset(gr, 0, 2 * ((size_t)mh + 1) * l->gw * sizeof(double));
    const size_t ks = ((2 * (size_t)nh + 1 + 3) & ~(size_t)3) + 8;
    size_t room = (size_t)WF_PROFILE_KNOT_BLOCK * (size_t)w->cap_line / ks;
    int per = room > (size_t)WF_PROFILE_MAX_KNOTS ? WF_PROFILE_MAX_KNOTS : (int)room;
    double ckr[WF_PROFILE_MAX_KNOTS], cki[WF_PROFILE_MAX_KNOTS], wk[WF_PROFILE_MAX_KNOTS];
    double thx[WF_PROFILE_MAX_KNOTS], thy[WF_PROFILE_MAX_KNOTS];
    const double half = 0.5 * wd * delta, norm = jb->fknot / ((double)wd * wd);
    for (int k0 = 0; k0 < l->nk; k0 += per) {
        int nkb = l->nk - k0 < per ? l->nk - k0 : per;
        for (int j = 0; j < nkb; j++) {
            const double *kp = l->pos + 2 * (size_t)(k0 + j);
            double x = kp[0] + gd->dx, y = kp[1] + gd->dy;
            thx[j] = delta * x;
            thy[j] = delta * y;
            wk[j] = norm / (wf_knot_kernel_ft(half * x, l->beta) *
                            wf_knot_kernel_ft(half * y, l->beta));
        }
        wf_profile_phase_lines(nkb, thx, -nh, nh, w->kx, 2 * ks, ks, 1, 0);
        wf_profile_phase_lines(nkb, thy, 0, mh, w->ky, 2 * ks, ks, 1, 0);
        for (int m = 0; m <= mh; m++) {
            int ns = lat_nmax(l, m), nn = lat_nmax(l, -m);
            if (nn > ns) ns = nn;
            if (ns < 0) continue;
            for (int j = 0; j < nkb; j++) {
                const double *ly = w->ky + 2 * (size_t)j * ks + (size_t)m;
                ckr[j] = wk[j] * ly[0];
                cki[j] = wk[j] * ly[ks];
            }
            size_t off = (size_t)(nh - ns);
            wf_profile_knot_sum((2 * ns + 1 + 7) & ~7, nkb, ckr, cki, w->kx + off, ks,
                                gr + (size_t)m * l->gw + off, gi + (size_t)m * l->gw + off);
        }
    }
    l->gr = gr;
    l->gi = gi;
    l->al = 2 * (size_t)l->U + 1 + 8;
    l->ar = w->ring;
    l->ai = w->ring + (size_t)wd * l->al;
    l->tmp = w->ring + 2 * (size_t)wd * l->al;
    l->next = wf_floor_div(-l->U, r) - wd / 2 + 1;
}

typedef struct knot_rank {
    double e; /* max(|x|, |y|) from the object */
    int j;
} knot_rank;

static int rank_cmp(const void *pa, const void *pb)
{
    const knot_rank *a = pa, *b = pb;
    if (a->e != b->e) return a->e < b->e ? 1 : -1; /* farthest first */
    return (a->j > b->j) - (a->j < b->j);
}

#define LAT_OUTER_MAX 32

/* Chooses the kernel, how many of the farthest knots to sum directly and the lattice for
 * the rest, by operation count; reorders gd->kpos (the direct ones first, then the
 * lattice's, each in a fixed order). 0: all knots directly. */
int wf_profile_knot_plan(wf_profile_work *w, wf_draw_grid *gd, double p, wf_knot_lattice *l)
{
    static const int widths[] = {6, 8, 10, 12, 14, 16};
    const int nk = gd->nk, forced = w->knot_method == WF_KNOTS_LATTICE;
    knot_rank rk[WF_PROFILE_MAX_KNOTS];
    for (int j = 0; j < nk; j++) {
        double x = fabs(gd->kpos[2 * j] + gd->dx), y = fabs(gd->kpos[2 * j + 1] + gd->dy);
        rk[j] = (knot_rank){x > y ? x : y, j};
    }
    qsort(rk, (size_t)nk, sizeof *rk, rank_cmp);
    const double fine = 0.5 * M_PI * (double)gd->u * gd->u;
    /* the direct sum unless the lattice saves a fifth: planning and setup are not counted */
    double best = forced ? INFINITY : 0.8 * nk * fine;
    int best_o = -1, best_r = 0, best_w = 0;
    int omax = forced ? 0 : nk - 1 < LAT_OUTER_MAX ? nk - 1 : LAT_OUTER_MAX;
    for (size_t iw = 0; iw < sizeof widths / sizeof *widths; iw++) {
        int last_r = 0;
        double c0 = 0.0, c1 = 0.0;
        for (int no = 0; no <= omax; no++) {
            int r = lat_step(gd, p, rk[no].e, widths[iw]);
            if (!r) continue;
            if (r != last_r) {
                if (!lat_size(w, gd, r, widths[iw], l, &c0, &c1)) continue;
                last_r = r;
            }
            double c = c0 + c1 * (nk - no) + (double)no * fine;
            if (c < best) {
                best = c;
                best_o = no;
                best_r = r;
                best_w = widths[iw];
            }
        }
    }
    double c0, c1;
    if (best_o < 0 || !lat_size(w, gd, best_r, best_w, l, &c0, &c1)) return 0;
    l->nk = nk - best_o;
    /* the direct ones in rank order, then the rest in their own order */
    double tmp[2 * WF_PROFILE_MAX_KNOTS];
    unsigned char outer[WF_PROFILE_MAX_KNOTS];
    memset(outer, 0, (size_t)nk);
    int k = 0;
    for (int i = 0; i < best_o; i++, k++) {
        outer[rk[i].j] = 1;
        tmp[2 * k] = gd->kpos[2 * rk[i].j];
        tmp[2 * k + 1] = gd->kpos[2 * rk[i].j + 1];
    }
    for (int j = 0; j < nk; j++)
        if (!outer[j]) {
            tmp[2 * k] = gd->kpos[2 * j];
            tmp[2 * k + 1] = gd->kpos[2 * j + 1];
            k++;
        }
    memcpy(w->knot_box, tmp, 2 * (size_t)nk * sizeof(double));
    gd->kpos = w->knot_box;
    l->pos = w->knot_box + 2 * (size_t)best_o;
    return 1;
}

/* Coarse row m interpolated along u into its ring slot, at the u of the alias runs
 * wf_profile_fold_pass visits. */
void wf_profile_lat_row(const wf_fold_kernels *fk, wf_knot_lattice *l, int m, int mbox)
{
    const int wd = l->w, nh = l->nh;
    int um = lat_umax(l, m);
    if (um < 0) return;
    int slot = ((m % wd) + wd) % wd;
    double *ar = l->ar + (size_t)slot * l->al + l->U, *ai = l->ai + (size_t)slot * l->al + l->U;
    const double *gr = l->gr + (size_t)(m < 0 ? -m : m) * l->gw + nh;
    const double *gi = l->gi + (size_t)(m < 0 ? -m : m) * l->gw + nh;
    if (m < 0) { /* g(n, m) = conj g(-n, -m) */
        int ns = lat_nmax(l, m), nn = lat_nmax(l, -m);
        if (nn > ns) ns = nn;
        double *tr = l->tmp + ns, *ti = l->tmp + (2 * ns + 1) + ns;
        for (int n = -ns; n <= ns; n++) {
            tr[n] = gr[-n];
            ti[n] = -gi[-n];
        }
        gr = tr;
        gi = ti;
    }
    const int half = mbox / 2;
    for (int a = wf_floor_div(-um, mbox); a <= wf_floor_div(um, mbox); a++) {
        int ua = a * mbox > -um ? a * mbox : -um;
        int ub = a * mbox + half < um ? a * mbox + half : um;
        if (ua <= ub) fk->latrow(l, gr, gi, ua, ub, ar, ai);
    }
}
