/* The drawer's knobs and memory: the accuracy settings and their checks, the FFT sides a
 * work draws with, the work's buffers laid out in its arena (what draws touch, what they
 * zero), and the FFT plans every work of the process shares. */
#include <fftw3.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"
#include "sim/numeric/fftw_lock.h"

void wf_profile_accuracy_default(wf_profile_accuracy *acc)
{
    acc->pixel_scale = WF_PROFILE_PIXEL_SCALE;
    acc->flux_fraction = 0.995;
    acc->folding_threshold = 5e-3;
    acc->kvalue_accuracy = 1e-5;
    acc->min_fft = 16;
    acc->max_fft = 1024;
    acc->psf_table_fft = 192;
    acc->extra_tables = 1;
    acc->core_radius = 0.0;
    acc->core_levels = 1;
    acc->wing_tolerance = 0.0;
    acc->knot_accuracy = WF_PROFILE_KNOT_ACCURACY;
    acc->cut_tolerance = 0.0;
}

wf_status wf_profile_check_accuracy(const wf_profile_accuracy *acc)
{
    if (!acc) return wf_error(WF_ERR_INPUT, "profile: no accuracy settings");
    if (!(acc->pixel_scale > 0.0 && acc->pixel_scale < 10.0))
        return wf_error(WF_ERR_RANGE, "profile: pixel scale %g arcsec outside (0, 10)",
                        acc->pixel_scale);
    if (!(acc->flux_fraction > 0.0 && acc->flux_fraction < 1.0))
        return wf_error(WF_ERR_RANGE, "profile: flux_fraction %g outside (0, 1)",
                        acc->flux_fraction);
    if (!(acc->folding_threshold >= 1e-12 && acc->folding_threshold <= 0.5))
        return wf_error(WF_ERR_RANGE, "profile: folding_threshold %g outside [1e-12, 0.5]",
                        acc->folding_threshold);
    if (!(acc->kvalue_accuracy >= 1e-15 && acc->kvalue_accuracy <= 0.1))
        return wf_error(WF_ERR_RANGE, "profile: kvalue_accuracy %g outside [1e-15, 0.1]",
                        acc->kvalue_accuracy);
    if (acc->min_fft < 8 || acc->max_fft < acc->min_fft || acc->max_fft > 16384)
        return wf_error(WF_ERR_RANGE, "profile: FFT sides [%d, %d] not within [8, 16384]",
                        acc->min_fft, acc->max_fft);
    if (!(acc->core_radius >= 0.0 && acc->core_radius <= 60.0))
        return wf_error(WF_ERR_RANGE, "profile: core_radius %g arcsec outside [0, 60]",
                        acc->core_radius);
    if (acc->core_levels < 1 || acc->core_levels > WF_PROFILE_MAX_CORES)
        return wf_error(WF_ERR_RANGE, "profile: core_levels %d outside [1, %d]",
                        acc->core_levels, WF_PROFILE_MAX_CORES);
    if (!(acc->knot_accuracy >= 1e-15 && acc->knot_accuracy <= 0.01))
        return wf_error(WF_ERR_RANGE, "profile: knot_accuracy %g outside [1e-15, 0.01]",
                        acc->knot_accuracy);
    if (!(acc->wing_tolerance >= 0.0 && acc->wing_tolerance < INFINITY))
        return wf_error(WF_ERR_RANGE, "profile: wing_tolerance %g is not a finite value >= 0",
                        acc->wing_tolerance);
    if (!(acc->cut_tolerance >= 0.0 && acc->cut_tolerance < INFINITY))
        return wf_error(WF_ERR_RANGE, "profile: cut_tolerance %g is not a finite value >= 0",
                        acc->cut_tolerance);
    /* even also because the PSF tables' batched real transforms are planned without
     * buffering (sim/draw/profile_psf.c), which FFTW cannot do for odd lengths past 15 */
    if (acc->extra_tables != 0 && acc->extra_tables != 1)
        return wf_error(WF_ERR_RANGE, "profile: extra_tables %d is not 0 or 1", acc->extra_tables);
    if (acc->psf_table_fft < 16 || acc->psf_table_fft > 4096 || acc->psf_table_fft % 2)
        return wf_error(WF_ERR_RANGE, "profile: psf_table_fft %d not an even number in "
                        "[16, 4096]", acc->psf_table_fft);
    return WF_OK;
}

/* ------------------------------------------------------------------------ work buffers */

int wf_profile_fft_ladder(const wf_profile_accuracy *acc, int *sizes, int cap)
{
    int n = 0;
    for (int m = 8; m <= acc->max_fft && n < cap; m += 2) {
        int r = m;
        while (r % 2 == 0) r /= 2;
        if (r != 1 && r != 3 && r != 5 && r != 7) continue;
        if (m < acc->min_fft) continue;
        sizes[n++] = m;
    }
    return n;
}

int wf_profile_table_of(const int *per, int n, int m)
{
    for (int i = 0; i < n; i++)
        if (m <= per[i] && per[i] % m == 0) return i;
    return -1;
}

int wf_profile_psf_period(const wf_profile_psf *psf, int m)
{
    int per[1 + WF_PROFILE_MAX_ALT];
    per[0] = psf->table_fft;
    for (int i = 0; i < psf->nalt; i++) per[1 + i] = psf->alt[i].fft;
    return wf_profile_table_of(per, 1 + psf->nalt, m);
}

int wf_profile_table_periods(const wf_profile_accuracy *acc, int *per)
{
    int sizes[48], ns = wf_profile_fft_ladder(acc, sizes, 48), n = 1;
    per[0] = acc->psf_table_fft;
    for (int i = ns - 1; i >= 0 && acc->extra_tables && n < 1 + WF_PROFILE_MAX_ALT; i--)
        if (sizes[i] < per[0] && wf_profile_table_of(per, n, sizes[i]) < 0) per[n++] = sizes[i];
    return n;
}

typedef struct work_layout {
    int nsizes, sizes[48], max_m, cap_line;
} work_layout;

static void layout(const wf_profile_accuracy *acc, work_layout *l)
{
    l->nsizes = wf_profile_fft_ladder(acc, l->sizes, 48);
    l->max_m = l->nsizes ? l->sizes[l->nsizes - 1] : 0;
    /* |k| <= WF_PSF_BAND_NYQ pi / p is |u| <= WF_PSF_BAND_NYQ M / 2 steps */
    l->cap_line = 2 * ((int)ceil(0.5 * WF_PSF_BAND_NYQ * l->max_m) + 2) + 1;
}

/* Doubles for the knot lattice: (U / r + w) rows of 2 U / r + w entries, re and im, for
 * U ~ 1.2 M at Y106 and r >= 2, so an eighth of max_m^2 holds every lattice of boxes up to
 * M = 512 and the coarser ones beyond; the others fall back to the direct sum. */
static size_t lattice_cap(const work_layout *l)
{
    size_t m = (size_t)l->max_m;
    return m * m / 8 > 65536 ? m * m / 8 : 65536;
}

/* Doubles for the lattice's interpolated rows (up to WF_LAT_WMAX of them, re and im, 2 U + 9
 * entries each) and one mirrored coarse row: room for U up to half cap_line (~2 M, the
 * band of every filter redder than 0.6 um). */
static size_t lattice_ring(const work_layout *l)
{
    return 2 * (size_t)WF_LAT_WMAX * ((size_t)l->cap_line / 2 + 9) + (size_t)l->cap_line;
}

/* The zero-filled buffers, which wf_profile_work_init lays out first, and the rest, which
 * draws touch only as far as they reach. */
static size_t dense_bytes(const work_layout *l)
{
    size_t m = (size_t)l->max_m, d = sizeof(double);
    return 2 * wf_arena_cost((size_t)l->cap_line * 2 * d) + 2 * wf_arena_cost((size_t)l->cap_line * sizeof(int)) +
           2 * wf_arena_cost((size_t)l->cap_line * 4 * d) + wf_arena_cost((m / 2 + 8) * 4 * d) +
           2 * wf_arena_cost((size_t)WF_PROFILE_MAX_KNOTS * 2 * d) + wf_arena_cost(lattice_ring(l) * d) +
           wf_arena_cost((size_t)l->cap_line * sizeof(int));
}

static size_t sparse_bytes(const work_layout *l)
{
    size_t m = (size_t)l->max_m, d = sizeof(double);
    return wf_arena_cost(m * (m + 2) * d) + 2 * wf_arena_cost((size_t)WF_PROFILE_KNOT_BLOCK * l->cap_line * 2 * d) +
           wf_arena_cost(lattice_cap(l) * d);
}

wf_status wf_profile_work_need(const wf_profile_accuracy *acc, size_t *bytes, size_t *dense)
{
    wf_status st = wf_profile_check_accuracy(acc);
    if (st) return st;
    work_layout l;
    layout(acc, &l);
    if (!l.nsizes)
        return wf_error(WF_ERR_RANGE, "profile: no FFT side of the form 2^a, 3 2^a, 5 2^a or 7 2^a in "
                        "[%d, %d]", acc->min_fft, acc->max_fft);
    *bytes = dense_bytes(&l) + sparse_bytes(&l);
    if (dense) *dense = dense_bytes(&l);
    return WF_OK;
}

wf_status wf_profile_work_init(wf_profile_work *w, const wf_profile_accuracy *acc,
                               wf_arena *arena)
{
    memset(w, 0, sizeof *w);
    size_t need;
    wf_status st = wf_profile_work_need(acc, &need, NULL);
    if (st) return st;
    w->acc = *acc;
    work_layout l;
    layout(acc, &l);
    size_t m = (size_t)l.max_m, d = sizeof(double);
    /* The zero-filled buffers first (wf_profile_work_need's `dense`: a host may put them on
     * huge pages). The FFT buffer, the knot phase lines and the knot lattice come after and
     * are not zeroed: each draw clears or writes what it reads (the lines' padding lanes only
     * feed unused sums), so pages beyond the largest box drawn are never touched and cost no
     * resident memory. */
    if ((st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ex)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 2, d, "profile phases",
                              (void **)&w->ey)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->ix)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "PSF taps",
                              (void **)&w->iy)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wx)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line * 4, d, "PSF weights",
                              (void **)&w->wy)) ||
        (st = wf_arena_calloc(arena, (m / 2 + 8) * 4, d, "profile run", (void **)&w->run)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_pos)) ||
        (st = wf_arena_calloc(arena, (size_t)WF_PROFILE_MAX_KNOTS * 2, d, "knot positions",
                              (void **)&w->knot_box)) ||
        (st = wf_arena_calloc(arena, lattice_ring(&l), d, "knot lattice rows",
                              (void **)&w->ring)) ||
        (st = wf_arena_calloc(arena, (size_t)l.cap_line, sizeof(int), "profile rows",
                              (void **)&w->rim)) ||
        (st = wf_arena_reserve(arena, m * (m + 2) * d, "profile FFT", (void **)&w->fft)) ||
        (st = wf_arena_reserve(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2 * d,
                               "knot phases", (void **)&w->kx)) ||
        (st = wf_arena_reserve(arena, (size_t)WF_PROFILE_KNOT_BLOCK * l.cap_line * 2 * d,
                               "knot phases", (void **)&w->ky)) ||
        (st = wf_arena_reserve(arena, lattice_cap(&l) * d, "knot lattice", (void **)&w->lat)))
        return st;
    w->cap_lat = lattice_cap(&l);
    w->cap_line = l.cap_line;
    w->sersic = wf_sersic4_table();
    w->nsizes = l.nsizes;
    memcpy(w->sizes, l.sizes, sizeof w->sizes);
    /* the plans come with the first draw of each side (wf_profile_draw_plan) */
    if ((uintptr_t)w->fft % 16)
        return wf_error(WF_ERR_INTERNAL, "profile: FFT buffer not 16-byte aligned");
    return WF_OK;
}

void wf_profile_work_free(wf_profile_work *w)
{
    if (!w) return;
    memset(w->plans, 0, sizeof w->plans); /* shared: they stay (wf_profile_draw_plan) */
    w->nsizes = 0;
}

/* The drawer's plans: one in-place n x n complex-to-real transform per side, made on first
 * use and shared by every work of the process, as every work's buffer has rows of n + 2 and
 * FFTW's alignment (16 bytes), all new-array execution asks. Planning costs up to ~4 ms a
 * side even with FFTW_ESTIMATE (a 3 x 2^a side the most), per thread when each work made
 * its own for the whole ladder; a scene uses a few sides. FFTW_ESTIMATE reads no array, so
 * a plan may be made while the buffer holds a draw's input. Kept for the process's life. */
static void *shared_plans[4 * 15];

static int side_index(int n)
{
    static const int odd[4] = {1, 3, 5, 7};
    int f = n % 3 == 0 ? 1 : n % 5 == 0 ? 2 : n % 7 == 0 ? 3 : 0, m = n / odd[f], a = 0;
    while (m > 1) m >>= 1, a++;
    return 4 * a + f;
}

/* From side 64 up, FFTW_ESTIMATE alone picks plans that copy the 3-point passes through
 * buffers which each execution allocates and frees (malloc, and its consolidation, was ~1.7%
 * of the GalSim scene's samples); FFTW_NO_BUFFERING (fftw3.h's planner flags) leaves them
 * out: 96^2 43 -> 22 us, 192^2 146 -> 107 us, 384^2 555 -> 396 us, 64^2 and 128^2 the same on
 * this machine. At 48^2 buffering is faster (5.4 against 6.1 us), so it stays below 64. The
 * planner still reads no array: the plan is a function of the side, and so are the bits. */
static unsigned draw_plan_flags(int n) { return FFTW_ESTIMATE | (n >= 64 ? FFTW_NO_BUFFERING : 0u); }

wf_status wf_profile_draw_plan(wf_profile_work *w, int mi)
{
    if (w->plans[mi]) return WF_OK;
    int n = w->sizes[mi], ix = side_index(n);
    if (ix < 0 || ix >= (int)(sizeof shared_plans / sizeof *shared_plans))
        return wf_error(WF_ERR_INTERNAL, "profile: FFT side %d has no plan slot", n);
    wf_fftw_lock();
    if (!shared_plans[ix])
        shared_plans[ix] = fftw_plan_dft_c2r_2d(n, n, (fftw_complex *)w->fft, w->fft, draw_plan_flags(n));
    w->plans[mi] = shared_plans[ix];
    wf_fftw_unlock();
    if (!w->plans[mi]) return wf_error(WF_ERR_INTERNAL, "profile: FFTW could not plan a %d^2 FFT", n);
    return WF_OK;
}

void wf_profile_knot_method(wf_profile_work *work, int method) { work->knot_method = method; }

void wf_profile_keep_negatives(wf_profile_work *work, int keep) { work->keep_negatives = keep != 0; }

wf_status wf_profile_work_tune_cut(wf_profile_work *work, double cut_tolerance)
{
    wf_profile_accuracy acc = work->acc;
    acc.cut_tolerance = cut_tolerance;
    wf_status st = wf_profile_check_accuracy(&acc);
    if (st) return st;
    work->acc = acc;
    return WF_OK;
}

wf_status wf_profile_work_tune(wf_profile_work *work, double flux_fraction,
                               double folding_threshold, double kvalue_accuracy,
                               double wing_tolerance, double knot_accuracy)
{
    wf_profile_accuracy acc = work->acc;
    acc.flux_fraction = flux_fraction;
    acc.folding_threshold = folding_threshold;
    acc.kvalue_accuracy = kvalue_accuracy;
    acc.wing_tolerance = wing_tolerance;
    acc.knot_accuracy = knot_accuracy;
    wf_status st = wf_profile_check_accuracy(&acc);
    if (st) return st;
    work->acc = acc;
    return WF_OK;
}
