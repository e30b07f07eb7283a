#include "sim/draw/scene.h"

#include <fitsio.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hal/arena.h"
#include "sim/optics/bandpass.h"
#include "sim/fits/fitsout.h"
#include "sim/numeric/parallel.h"
#include "sim/draw/plane_cache.h"
#include "sim/draw/profile.h"
#include "sim/draw/render.h"
#include "sim/draw/scene_psf.h"
#include "sim/optics/sky.h"
#include "sim/survey/wcs.h"

#define SKY_GRID 64 /* pixel-area samples every 64 pixels, bilinear between: the area varies
                       by ~3% across the SCA, smoothly, so the interpolation error is ~1e-6 */

typedef enum { OBJ_GALAXY = 0, OBJ_STAR = 1, OBJ_SN = 2 } obj_kind;

typedef struct object {
    obj_kind kind;
    size_t row;       /* catalog row */
    double x, y;      /* 0-based pixel */
    double ra, dec, mag, flux;
    wf_galaxy g;      /* galaxies: pixel-frame shape */
    int wide;         /* bright point source: the wide PSF */
    int smooth_knots; /* its knots drawn as the smooth disk (noise_tolerance; g.n_knots 0) */
    double fold, kval, wing_tol, knot_acc; /* its folding threshold, Fourier cut, wing
                                            * tolerance and knot accuracy (noise_tolerance) */
} object;

typedef struct object_plan {
    wf_stamp bounds, box; /* stamp bounds; the part kept in the pool */
    int split;            /* a galaxy drawn with the split PSF (box only, wing per row): the
                           * core's index + 1, else 0 */
} object_plan;

typedef struct thread_state {
    wf_scene *scene;
    void *memory;
    wf_arena arena;
    wf_profile_work work;
    int work_ready;
    double *stamp;    /* the largest stamp, for objects asked for in pieces */
    size_t stamp_cap;
    wf_renderer *renderer;
    /* the wing placed last, and for what: the renderer asks for an object's rows one after
     * another, and the placement costs more than a row of the wing */
    const wf_render_object *wing_obj;
    double wing_key[3]; /* flux, x, y */
    wf_profile_wing_at wing;
} thread_state;

typedef struct works_job {
    wf_scene *s;
    wf_status st;
    char message[512];
} works_job;

struct wf_scene {
    wf_scene_setup setup;
    object_plan *plans;      /* while building: per object */
    wf_filter filter;
    wf_focal_plane fp;
    wf_wcs wcs;
    wf_bandpass *bp;
    double zodi;             /* e-/s/arcsec^2 */
    double thermal;          /* e-/pixel/s */
    int gx, gy;              /* pixel-area grid */
    double *area;            /* arcsec^2, (gy x gx) */
    wf_scene_psf *psf;       /* the PSF and its tables, the setup's cache's or the scene's own */
    wf_profile_psf ppsf;     /* psf's tables, and its wide PSF's once built */
    wf_profile_accuracy acc;
    wf_profile_psf ppsf_wide;
    object *obj;
    size_t nobj;
    const uint8_t *layer_gal, *layer_star; /* wf_scene_set_layer */
    void (*layer_fn)(void *, int, const float *, int);
    void *layer_ctx;
    double layer_floor;
    wf_plane_entry *plane; /* the static plane's entry (wf_scene_set_plane), owned */
    int plane_found;       /* 1: the plane comes from it, static objects are not drawn */
    long sne_wide;         /* supernovae drawn with the wide PSF (not the plane's) */
    wf_render_object *robj;
    size_t nrobj;            /* objects the renderer draws (SNe of zero flux are not drawn) */
    int time_variable;       /* some drawn object has a flux slope */
    thread_state *ts;
    const wf_catalog *gal, *stars;
    wf_scene_stats stats;
    /* from wf_scene_prepare to wf_scene_populate: the helper making the works */
    works_job works;
    pthread_t works_thread;
    int works_running, prepared;
    double t0;
};

void wf_scene_setup_default(wf_scene_setup *s)
{
    memset(s, 0, sizeof *s);
    s->ra = 71.0;
    s->dec = -53.0;
    s->pa = 0.0;
    s->sca = 1;
    snprintf(s->filter, sizeof s->filter, "Y106");
    s->mjd = 61420.0;
    s->ncols = s->nrows = 4088;
    s->pupil_bin = 8;
    s->psf_oversample = 4;
    s->psf_nlambda = 1;
    s->stray_light = 0.1;
    s->bright_mag = 15.0;
    s->psf_size = 256; /* 7" at 4x: drawing cost grows with its area (docs/BENCHMARKS.md) */
    s->flux_fraction = 0.995;
    s->core_radius = 2.0;
    s->core_levels = 3;
    s->noise_tolerance = 1.0;
    s->exptime = 300.0;
    s->pool_bytes = (size_t)24 << 20; /* float stamps; split galaxies keep only their core box */
    s->threads = 1;
    s->sky_on = 1;
}

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

/* Pixel area in arcsec^2 at 0-based (x, y), from the WCS by central differences. */
static wf_status pixel_area(const wf_wcs *w, double x, double y, double *area)
{
    double r[4], d[4];
    const double h = 0.5;
    wf_status st;
    if ((st = wf_wcs_pix2world(w, x - h, y, &r[0], &d[0])) || (st = wf_wcs_pix2world(w, x + h, y, &r[1], &d[1])) ||
        (st = wf_wcs_pix2world(w, x, y - h, &r[2], &d[2])) || (st = wf_wcs_pix2world(w, x, y + h, &r[3], &d[3])))
        return st;
    double c = cos(d[0] * M_PI / 180.0);
    double dra_x = r[1] - r[0], dra_y = r[3] - r[2];
    if (dra_x > 180) dra_x -= 360;
    if (dra_x < -180) dra_x += 360;
    if (dra_y > 180) dra_y -= 360;
    if (dra_y < -180) dra_y += 360;
    double ax = dra_x * c * 3600.0, bx = (d[1] - d[0]) * 3600.0;
    double ay = dra_y * c * 3600.0, by = (d[3] - d[2]) * 3600.0;
    *area = fabs(ax * by - ay * bx);
    return WF_OK;
}

static wf_status sky_row(void *ctx, int y, int ncols, double *out)
{
    const wf_scene *s = ctx;
    if (!s->setup.sky_on) {
        for (int x = 0; x < ncols; x++) out[x] = 0.0;
        return WF_OK;
    }
    double fy = (double)y / SKY_GRID;
    int j = (int)fy;
    if (j > s->gy - 2) j = s->gy - 2;
    double ty = fy - j;
    const double *a0 = s->area + (size_t)j * s->gx, *a1 = a0 + s->gx;
    double zodi = s->zodi * (1.0 + s->setup.stray_light), thermal = s->thermal;
    /* cell by cell: the four corners stay in registers (the same operations per pixel as
     * one loop over x that looks the cell up, so the same bits) */
    for (int x0 = 0; x0 < ncols;) {
        int i = x0 / SKY_GRID;
        if (i > s->gx - 2) i = s->gx - 2;
        int x1 = i == s->gx - 2 ? ncols : (i + 1) * SKY_GRID;
        if (x1 > ncols) x1 = ncols;
        const double p = a0[i], q = a0[i + 1], r = a1[i], t = a1[i + 1];
        double *o = out + x0;
        if (x1 - x0 == SKY_GRID && x0 == i * SKY_GRID) {
            /* x / SKY_GRID - i is k / SKY_GRID exactly; a fixed trip count lets -O2 vectorise */
            for (int k = 0; k < SKY_GRID; k++) {
                double tx = (double)k / SKY_GRID;
                o[k] = zodi * ((1 - ty) * ((1 - tx) * p + tx * q) + ty * ((1 - tx) * r + tx * t)) + thermal;
            }
        } else {
            for (int x = x0; x < x1; x++) {
                double tx = (double)x / SKY_GRID - i;
                out[x] = zodi * ((1 - ty) * ((1 - tx) * p + tx * q) + ty * ((1 - tx) * r + tx * t)) + thermal;
            }
        }
        x0 = x1;
    }
    return WF_OK;
}

/* Sky-frame shape (u west, v north, arcsec) to the pixel frame the drawer uses (arcsec along
 * x and y at the nominal 0.11" scale): the second-moment matrix C of the sheared, rotated
 * round profile goes through the local Jacobian T; its determinant gives the size scale and
 * its trace-free part the pixel-frame distortion. */
static wf_status pixel_shape(const wf_scene *s, double x, double y, double e1, double e2,
                             double pa_deg, double *pe1, double *pe2, double *scale)
{
    double ra0, dec0, xu, yu, xv, yv;
    const double step = 1.0 / 3600.0; /* one arcsec */
    wf_status st;
    if ((st = wf_wcs_pix2world(&s->wcs, x, y, &ra0, &dec0))) return st;
    double c = cos(dec0 * M_PI / 180.0);
    /* +u is west: decreasing RA */
    if ((st = wf_wcs_world2pix(&s->wcs, ra0 - step / c, dec0, &xu, &yu))) return st;
    if ((st = wf_wcs_world2pix(&s->wcs, ra0, dec0 + step, &xv, &yv))) return st;
    double t[2][2] = {{(xu - x) * WF_PROFILE_PIXEL_SCALE, (xv - x) * WF_PROFILE_PIXEL_SCALE},
                      {(yu - y) * WF_PROFILE_PIXEL_SCALE, (yv - y) * WF_PROFILE_PIXEL_SCALE}};
    double e = sqrt(e1 * e1 + e2 * e2);
    double norm = e < 1.0 ? 1.0 / sqrt(1.0 - e * e) : 1.0;
    double cw[2][2] = {{(1 + e1) * norm, e2 * norm}, {e2 * norm, (1 - e1) * norm}};
    double th = pa_deg * M_PI / 180.0, cs = cos(th), sn = sin(th);
    double r[2][2] = {{cs, -sn}, {sn, cs}};
    double m[2][2], cr[2][2], cp[2][2];
    /* cr = R cw R^T */
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) m[i][j] = r[i][0] * cw[0][j] + r[i][1] * cw[1][j];
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) cr[i][j] = m[i][0] * r[j][0] + m[i][1] * r[j][1];
    /* cp = T cr T^T */
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) m[i][j] = t[i][0] * cr[0][j] + t[i][1] * cr[1][j];
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++) cp[i][j] = m[i][0] * t[j][0] + m[i][1] * t[j][1];
    double tr = cp[0][0] + cp[1][1];
    *pe1 = (cp[0][0] - cp[1][1]) / tr;
    *pe2 = 2.0 * cp[0][1] / tr;
    *scale = sqrt(fabs(t[0][0] * t[1][1] - t[0][1] * t[1][0]));
    return WF_OK;
}

/* Rows [ya, yb) of the object's box: its whole stamp, or for a galaxy drawn with the split
 * PSF (ro->halo) the Fourier box of galaxy x core, its wing added by halo_row. */
static wf_status draw_object(void *ctx, const wf_render_object *ro, int ya, int yb, double *out)
{
    thread_state *ts = ctx;
    const object *o = ro->data;
    size_t whole = (size_t)ro->bnx * ro->bny;
    int full = ya == ro->by0 && yb == ro->by0 + ro->bny;
    double *buf = out;
    if (!full) {
        if (whole > ts->stamp_cap) {
            double *p = realloc(ts->stamp, whole * sizeof *p);
            if (!p) return wf_error(WF_ERR_NOMEM, "scene: cannot hold a %d x %d stamp", ro->bnx, ro->bny);
            ts->stamp = p;
            ts->stamp_cap = whole;
        }
        buf = ts->stamp;
    }
    wf_stamp st = {ro->bx0, ro->by0, ro->bnx, ro->bny, buf, 0, 0, 0};
    const wf_profile_accuracy *acc = &ts->scene->acc;
    wf_status s = wf_profile_work_tune(&ts->work, acc->flux_fraction, o->fold, o->kval, o->wing_tol, o->knot_acc);
    if (!s) s = wf_profile_work_tune_cut(&ts->work, o->wing_tol);
    if (s) return s;
    s = o->kind != OBJ_GALAXY ? wf_profile_draw_point(&ts->work, o->wide ? &ts->scene->ppsf_wide : &ts->scene->ppsf,
                                                      o->flux, o->x, o->y, &st)
        : ro->halo            ? wf_profile_draw_galaxy_core(&ts->work, &o->g, &ts->scene->ppsf, o->x, o->y, &st)
                              : wf_profile_draw_galaxy(&ts->work, &o->g, &ts->scene->ppsf, o->x, o->y, &st);
    if (s) return s;
    if (!full) memcpy(out, buf + (size_t)(ya - ro->by0) * ro->bnx, (size_t)(yb - ya) * ro->bnx * sizeof *out);
    return WF_OK;
}

/* A split galaxy's wing over row y, columns [xa, xb), with its box's pixels: recomputed as
 * the tiles pass, so that the pool keeps only the core box (a few times smaller than the
 * stamp). */
static wf_status halo_row(void *ctx, const wf_render_object *ro, int y, int xa, int xb,
                          const float *box, int ca, int cb, double *acc)
{
    thread_state *ts = ctx;
    const object *o = ro->data;
    if (ts->wing_obj != ro || ts->wing_key[0] != o->g.flux || ts->wing_key[1] != o->x ||
        ts->wing_key[2] != o->y) {
        ts->wing_obj = NULL;
        wf_status st = wf_profile_wing_place(&ts->scene->ppsf, ro->halo, o->g.flux, o->x, o->y, &ts->wing);
        if (st) return st;
        ts->wing.keep_negatives = ts->work.keep_negatives; /* as the box: the renderer clips the sum */
        ts->wing_obj = ro;
        ts->wing_key[0] = o->g.flux, ts->wing_key[1] = o->x, ts->wing_key[2] = o->y;
    }
    return wf_profile_add_wing_row(&ts->wing, y, xa, xb, box, ca, cb, acc);
}

static long long object_id(const wf_scene *s, const object *o)
{
    if (o->kind == OBJ_SN) return s->setup.sne[o->row].id;
    return (long long)(o->kind == OBJ_GALAXY ? s->gal->id[o->row] : s->stars->id[o->row]);
}

static wf_status grow(wf_scene *s, size_t *cap)
{
    if (s->nobj < *cap) return WF_OK;
    size_t nc = *cap ? 2 * *cap : 1024;
    object *p = wf_arena_host_realloc(s->obj, s->nobj * sizeof *p, nc * sizeof *p);
    if (!p) return wf_error(WF_ERR_NOMEM, "scene: cannot hold %zu objects", nc);
    s->obj = p;
    *cap = nc;
    return WF_OK;
}

/* Supernovae: point sources at the flux the caller evaluated for this exposure. */
static wf_status add_sne(wf_scene *s, size_t *cap)
{
    const double margin = 600.0;
    for (size_t i = 0; i < s->setup.nsne; i++) {
        const wf_scene_sn *sn = &s->setup.sne[i];
        double x, y;
        if (!isfinite(sn->mag) || !isfinite(sn->ra) || !isfinite(sn->dec))
            return wf_error(WF_ERR_RANGE, "scene: supernova %lld: magnitude or position is not finite", sn->id);
        if (wf_wcs_world2pix(&s->wcs, sn->ra, sn->dec, &x, &y) != WF_OK) continue;
        if (x < -margin || y < -margin || x > s->setup.ncols + margin || y > s->setup.nrows + margin) continue;
        wf_status st = grow(s, cap);
        if (st) return st;
        object *o = &s->obj[s->nobj++];
        memset(o, 0, sizeof *o);
        o->kind = OBJ_SN;
        o->row = i;
        o->x = x;
        o->y = y;
        o->ra = sn->ra;
        o->dec = sn->dec;
        o->mag = sn->mag;
        o->flux = sn->mag >= 99.0 ? 0.0 : wf_bandpass_countrate_ab(s->bp, sn->mag);
    }
    return WF_OK;
}

static wf_status add_objects(wf_scene *s, const wf_catalog *cat, obj_kind kind, size_t *cap)
{
    if (!cat || !cat->n) return WF_OK;
    int band;
    wf_status st = wf_catalog_band(cat, s->setup.filter, &band);
    if (st) return wf_error(st, "%s: no magnitude column for filter %s", cat->source, s->setup.filter);
    const double margin = 600.0; /* pixels: the largest stamp half-width the drawer allows */
    for (size_t i = 0; i < cat->n; i++) {
        double x, y;
        if (wf_wcs_world2pix(&s->wcs, cat->ra[i], cat->dec[i], &x, &y) != WF_OK) continue;
        if (x < -margin || y < -margin || x > s->setup.ncols + margin || y > s->setup.nrows + margin) continue;
        if ((st = grow(s, cap))) return st;
        object *o = &s->obj[s->nobj];
        memset(o, 0, sizeof *o);
        o->kind = kind;
        o->row = i;
        o->x = x;
        o->y = y;
        o->ra = cat->ra[i];
        o->dec = cat->dec[i];
        o->mag = cat->mag[band][i];
        o->flux = wf_bandpass_countrate_ab(s->bp, o->mag);
        if (kind == OBJ_GALAXY) {
            double pe1, pe2, scale;
            if ((st = pixel_shape(s, x, y, cat->e1[i], cat->e2[i], cat->pa[i], &pe1, &pe2, &scale))) return st;
            wf_galaxy *g = &o->g;
            /* the knot stream is keyed by a 32-bit id: fold the catalog's 64 bits */
            g->id = (uint32_t)((uint64_t)cat->id[i] ^ ((uint64_t)cat->id[i] >> 32));
            g->flux = o->flux;
            g->bulge_frac = cat->bulge_frac[i];
            g->hlr_bulge = cat->hlr_bulge[i] * scale;
            g->hlr_disk = cat->hlr_disk[i] * scale;
            g->knot_frac = cat->knot_frac[i];
            g->n_knots = g->knot_frac > 0 ? 100 : 0;
            g->knot_seed = (uint64_t)cat->id[i];
            g->e1 = pe1;
            g->e2 = pe2;
            g->rotation = 0.0;
        }
        s->nobj++;
    }
    return WF_OK;
}

/* Planning of the objects of range `task` (of s->setup.threads ranges) with the drawing work
 * of the thread that runs it (see wf_scene_create). */
static wf_status plan_range(void *ctx, int task, int slot)
{
    wf_scene *s = ctx;
    size_t T = (size_t)s->setup.threads, first = s->nobj * (size_t)task / T, end = s->nobj * (size_t)(task + 1) / T;
    wf_profile_work *w = &s->ts[slot].work;
    for (size_t i = first; i < end; i++) {
        const object *o = &s->obj[i];
        object_plan *pl = &s->plans[i];
        if (o->kind == OBJ_SN && !(o->flux > 0)) continue;
        if (s->plane_found && o->kind != OBJ_SN) continue; /* in the plane */
        wf_status st;
        if (o->kind == OBJ_GALAXY) { /* bounds, and a split galaxy's Fourier box (kept in the pool) */
            st = wf_profile_work_tune(w, s->acc.flux_fraction, o->fold, o->kval, o->wing_tol, o->knot_acc);
            if (!st) st = wf_profile_galaxy_core(w, &o->g, &s->ppsf, o->x, o->y, &pl->bounds, &pl->box, &pl->split);
        } else {
            st = wf_profile_point_bounds(w, o->wide ? &s->ppsf_wide : &s->ppsf, o->x, o->y, &pl->bounds, NULL);
            pl->box = pl->bounds;
        }
        if (st) return wf_error(st, "object %zu of the scene: %s", i, wf_error_message());
    }
    return WF_OK;
}

/* The drawing works, one per thread. They depend only on the accuracy knobs, so with more
 * than one thread they are made on a helper thread (works_job) while the sky and the PSF are
 * built (the first work also fills the Sersic table: ~40 ms of a serial set-up). */
static void *init_works(void *arg)
{
    works_job *j = arg;
    wf_scene *s = j->s;
    size_t wneed, dense;
    wf_status st = wf_profile_work_need(&s->acc, &wneed, &dense);
    for (int t = 0; !st && t < s->setup.threads; t++) {
        thread_state *ts = &s->ts[t];
        ts->scene = s;
        /* what the work fills at once on huge pages, the rest as the draws reach it */
        if (!(ts->memory = wf_arena_host_alloc_dense(wneed + 4096, dense))) {
            st = wf_error(WF_ERR_NOMEM, "scene: drawing arena");
            break;
        }
        wf_arena_init(&ts->arena, ts->memory, wneed + 4096, "drawing arena");
        if ((st = wf_profile_work_init(&ts->work, &s->acc, &ts->arena))) break;
        /* objects keep their ringing: the renderer clips the sum, so no draw adds flux */
        wf_profile_keep_negatives(&ts->work, 1);
        ts->work_ready = 1;
    }
    j->st = st;
    if (st) snprintf(j->message, sizeof j->message, "%s", wf_error_message());
    return NULL;
}

/* Independent per object, so planned by the threads in parallel, each with its own
 * drawing work; the first failure in object order is the one reported. */
static wf_status plan_objects(wf_scene *s)
{
    return wf_parallel_for(s->setup.threads, s->setup.threads, plan_range, s);
}

wf_status wf_scene_prepare(const wf_scene_setup *setup, wf_scene **out)
{
    *out = NULL;
    double t0 = now();
    wf_scene *s = calloc(1, sizeof *s);
    if (!s) return wf_error(WF_ERR_NOMEM, "scene: out of memory");
    s->setup = *setup;
    s->setup.sne = NULL; /* wf_scene_populate's */
    s->setup.nsne = 0;
    s->t0 = t0;
    const char *data = setup->data_dir[0] ? setup->data_dir : NULL;
    wf_status st;
    wf_sky_model *sky = NULL;
    s->works = (works_job){s, WF_OK, ""};
    if (setup->threads < 1) { st = wf_error(WF_ERR_RANGE, "scene: %d threads", setup->threads); goto bad; }
    wf_scene_psf_accuracy(setup, &s->acc); /* the PSF's tables are made under the same */
    if (!(s->ts = calloc((size_t)setup->threads, sizeof *s->ts))) {
        st = wf_error(WF_ERR_NOMEM, "scene: out of memory");
        goto bad;
    }
    /* the knobs are checked here, so that a bad one is reported the same whatever the thread
     * count; the helper can then fail only for memory or FFTW */
    size_t work_bytes;
    if ((st = wf_profile_work_need(&s->acc, &work_bytes, NULL))) goto bad;
    s->works_running = setup->threads > 1 && pthread_create(&s->works_thread, NULL, init_works, &s->works) == 0;
    if ((st = wf_filter_parse(setup->filter, &s->filter))) goto bad;
    if ((st = wf_wcs_focal_plane(data, &s->fp))) goto bad;
    if ((st = wf_wcs_for_sca(&s->fp, setup->ra, setup->dec, setup->pa, setup->sca, &s->wcs))) goto bad;
    if (!(s->bp = malloc(sizeof *s->bp)) || !(sky = malloc(sizeof *sky))) {
        st = wf_error(WF_ERR_NOMEM, "scene: out of memory");
        goto bad;
    }
    if ((st = wf_bandpass_load(s->filter, data, s->bp))) goto bad;
    /* sky: zodiacal level at the SCA centre (it varies by < 0.1% across 8'), thermal */
    if ((st = data ? wf_sky_load(data, sky) : wf_sky_builtin(sky))) goto bad;
    double rac, decc;
    if ((st = wf_wcs_pix2world(&s->wcs, (setup->ncols - 1) / 2.0, (setup->nrows - 1) / 2.0, &rac, &decc))) goto bad;
    if ((st = wf_sky_zodiacal(sky, s->filter, rac, decc, setup->mjd, &s->zodi))) goto bad;
    if ((st = wf_sky_thermal(s->filter, &s->thermal))) goto bad;
    s->gx = setup->ncols / SKY_GRID + 2;
    s->gy = setup->nrows / SKY_GRID + 2;
    if (!(s->area = malloc((size_t)s->gx * s->gy * sizeof *s->area))) { st = wf_error(WF_ERR_NOMEM, "scene: sky grid"); goto bad; }
    double zodi_least, area_min = INFINITY;
    if ((st = wf_sky_zodiacal_least(sky, s->filter, rac, decc, &zodi_least))) goto bad;
    s->stats.sky_min = INFINITY;
    s->stats.sky_max = -INFINITY;
    for (int j = 0; j < s->gy; j++)
        for (int i = 0; i < s->gx; i++) {
            if ((st = pixel_area(&s->wcs, i * SKY_GRID, j * SKY_GRID, &s->area[j * s->gx + i]))) goto bad;
            double v = s->zodi * (1 + s->setup.stray_light) * s->area[j * s->gx + i] + s->thermal;
            if (v < s->stats.sky_min) s->stats.sky_min = v;
            if (v > s->stats.sky_max) s->stats.sky_max = v;
            if (s->area[j * s->gx + i] < area_min) area_min = s->area[j * s->gx + i];
        }
    s->stats.sky_least = zodi_least * (1 + s->setup.stray_light) * area_min + s->thermal;
    s->stats.zodi = s->zodi;
    if ((st = wf_scene_psf_get(setup->psf_cache, setup, &s->psf))) goto bad;
    s->ppsf = s->psf->ppsf;
    s->stats.psf_lambda_nm = s->psf->lambda_nm;
    s->stats.psf_image_sum = s->psf->image_sum;
    s->stats.psf_pixel_max = s->ppsf.pixel_max;
    free(sky);
    s->prepared = 1;
    *out = s;
    return WF_OK;
bad:
    free(sky);
    wf_scene_destroy(s);
    return st;
}

/* The counts of the static objects: kept with a plane drawn, taken back with a plane given. */
static wf_status plane_counts(wf_scene *s)
{
    wf_scene_stats *t = &s->stats;
    if (!s->plane_found) {
        char note[256];
        snprintf(note, sizeof note, "galaxies %ld stars %ld split %ld smooth %ld bright %ld", t->galaxies, t->stars,
                 t->split, t->knots_smooth, t->bright - s->sne_wide);
        wf_plane_entry_set_note(s->plane, note);
        return WF_OK;
    }
    long g, st, sp, sm, b;
    if (sscanf(wf_plane_entry_note(s->plane), "galaxies %ld stars %ld split %ld smooth %ld bright %ld", &g, &st, &sp,
               &sm, &b) != 5)
        return wf_error(WF_ERR_INPUT, "scene: the plane's note \"%s\" does not give its counts",
                        wf_plane_entry_note(s->plane));
    t->galaxies = g, t->stars = st, t->split = sp, t->knots_smooth = sm, t->bright = b + s->sne_wide;
    return WF_OK;
}

wf_status wf_scene_populate(wf_scene *s, const wf_catalog *gal, const wf_catalog *stars,
                            const wf_scene_sn *sne, size_t nsne)
{
    if (!s || !s->prepared) return wf_error(WF_ERR_INTERNAL, "scene: populate needs a prepared scene, once");
    s->prepared = 0;
    s->gal = gal;
    s->stars = stars;
    s->setup.sne = sne;
    s->setup.nsne = nsne;
    const wf_scene_setup *setup = &s->setup;
    wf_status st;
    /* objects */
    size_t cap = 0;
    if ((st = add_objects(s, gal, OBJ_GALAXY, &cap)) || (st = add_objects(s, stars, OBJ_STAR, &cap)) ||
        (st = add_sne(s, &cap)))
        return st;
    /* a wide stamp reaches at most half the wide PSF image (2 psf_size / oversample pixels) */
    const double reach = 2.0 * setup->psf_size / setup->psf_oversample + 1.0;
    /* Per-object knobs from the noise (docs/ACCURACY.md): light wrapping into the Fourier
     * box stays in the stamp, moved across the box, and moves no pixel by more than
     * fold x flux; the Fourier modes dropped below kvalue x flux move none by more than their
     * count over the box's M^2 pixels, modes x kvalue x flux, with modes = pi (kmax p / 2 pi)^2
     * the fine-grid samples per box pixel out to the PSF's band (4.5 at Y106, 13 at R062), and
     * it moves further in where the sum over the modes beyond it bounds every pixel's change
     * by the same tolerance (acc.cut_tolerance, sim/draw/profile_size.c); the
     * split PSF's wing moves none by more than 2 flux wing_max; the knot lattice's aliasing
     * none by more than WF_SCENE_KNOT_BOUND knot_accuracy x the knots' flux (measured <= 0.13
     * in tests/test_profile.c); knots drawn as their expectation, the smooth disk, none by
     * more than the knots' flux x pixel_max (sim/draw/profile.h: both true images are non-negative
     * and neither exceeds it, a strict bound for the exact images; a draw in a smaller box adds
     * its own folding, which the folding knob bounds; measured <= 0.04 of that, ~0.1 with the box that changes with them,
     * over GalSim's scene). Each may be as large as
     * noise_tolerance x one pixel's sky noise over the exposure, in e-, at the least sky the
     * SCA has at this pointing on any date (sky_least): every exposure of a pointing, PA,
     * filter and SCA then draws its static objects alike, whatever its date, so that their
     * plane can be kept for the next (sim/draw/render.h). With no sky there is no noise to
     * hide in (unless sky_noise: the exposure had it, the rates leave it out). */
    if (!(setup->noise_tolerance >= 0.0 && setup->noise_tolerance < INFINITY)) {
        st = wf_error(WF_ERR_RANGE, "scene: noise_tolerance %g is not a finite value >= 0", setup->noise_tolerance);
        return st;
    }
    if (setup->noise_tolerance > 0.0 && !(setup->exptime > 0.0 && setup->exptime < INFINITY)) {
        st = wf_error(WF_ERR_RANGE, "scene: noise_tolerance %g needs a positive exposure time (%g s)",
                      setup->noise_tolerance, setup->exptime);
        return st;
    }
    const double kp = s->ppsf.kmax * s->acc.pixel_scale / (2.0 * M_PI), modes = M_PI * kp * kp;
    const int sky_noise = setup->sky_on || setup->sky_noise;
    const double sky_sigma = sky_noise && s->stats.sky_least > 0.0 ? sqrt(s->stats.sky_least * setup->exptime) : 0.0;
    const double tol_rate = setup->noise_tolerance > 0.0 ? setup->noise_tolerance * sky_sigma / setup->exptime : 0.0;
    for (size_t i = 0; i < s->nobj; i++) {
        object *o = &s->obj[i];
        o->fold = s->acc.folding_threshold;
        o->kval = s->acc.kvalue_accuracy;
        o->wing_tol = tol_rate; /* e-/s per pixel, the unit of the stamps */
        o->knot_acc = s->acc.knot_accuracy;
        const double knots = o->kind == OBJ_GALAXY && o->g.n_knots > 0 ? o->flux * (1.0 - o->g.bulge_frac) * o->g.knot_frac : 0.0;
        if (tol_rate > 0.0 && knots > 0.0 && knots * s->ppsf.pixel_max <= tol_rate) {
            o->g.n_knots = 0;
            o->smooth_knots = 1;
        } else if (tol_rate > 0.0 && knots > 0.0)
            o->knot_acc = fmin(WF_SCENE_KNOT_MAX, fmax(o->knot_acc, tol_rate / (WF_SCENE_KNOT_BOUND * knots)));
        if (tol_rate > 0.0 && o->flux > 0.0) {
            o->fold = fmin(WF_SCENE_FOLD_MAX, fmax(o->fold, tol_rate / o->flux));
            o->kval = fmin(WF_SCENE_KVALUE_MAX, fmax(o->kval, tol_rate / (modes * o->flux)));
        }
        int near = o->x > -reach && o->y > -reach && o->x < setup->ncols + reach && o->y < setup->nrows + reach;
        if (o->kind != OBJ_GALAXY && o->flux > 0 && o->mag < setup->bright_mag && near &&
            !(s->plane_found && o->kind != OBJ_SN)) {
            o->wide = 1;
            s->stats.bright++;
            s->sne_wide += o->kind == OBJ_SN;
        }
    }
    if (s->stats.bright) { /* built once, and only when a bright source is drawn */
        int had = s->psf->wide_built;
        if ((st = wf_scene_psf_wide(s->psf))) return st;
        s->ppsf_wide = s->psf->ppsf_wide;
        s->stats.wide_psf_seconds = had ? 0.0 : s->psf->wide_seconds;
    }
    if (!(s->robj = malloc((s->nobj ? s->nobj : 1) * sizeof *s->robj))) {
        st = wf_error(WF_ERR_NOMEM, "scene: out of memory");
        return st;
    }
    /* each thread: drawing work from its own arena (made by now on the helper thread, if
     * any), and a renderer */
    if (s->works_running) pthread_join(s->works_thread, NULL);
    else init_works(&s->works);
    s->works_running = 0;
    if (s->works.st) return wf_error(s->works.st, "%s", s->works.message);
    /* Each object's stamp bounds and, for a galaxy, whether it takes the split PSF and its
     * box: independent per object, so planned by the threads in parallel (each with its own
     * drawing work), then gathered in order. */
    if (!(s->plans = calloc(s->nobj ? s->nobj : 1, sizeof *s->plans))) {
        st = wf_error(WF_ERR_NOMEM, "scene: out of memory");
        return st;
    }
    if ((st = plan_objects(s))) return st;
    long kept = 0;
    for (size_t i = 0; i < s->nobj; i++) {
        object *o = &s->obj[i];
        if (o->kind == OBJ_SN && !(o->flux > 0)) continue; /* nothing to draw; truth only */
        if (s->plane_found && o->kind != OBJ_SN) continue;    /* in the plane */
        const object_plan *pl = &s->plans[i];
        const wf_stamp b = pl->bounds, box = pl->box;
        uint64_t id = (uint64_t)object_id(s, o);
        double rel = o->kind == OBJ_SN ? setup->sne[o->row].dlnf_dt : 0.0;
        if (!isfinite(rel)) {
            st = wf_error(WF_ERR_RANGE, "scene: supernova %lld: flux slope is not finite", object_id(s, o));
            return st;
        }
        const uint8_t *lf = o->kind == OBJ_GALAXY ? s->layer_gal : o->kind == OBJ_STAR ? s->layer_star : NULL;
        s->robj[kept++] = (wf_render_object){id * 4u + (uint64_t)o->kind, b.x0, b.y0, b.nx, b.ny, o, rel, pl->split,
                                             box.x0, box.y0, box.nx, box.ny, s->layer_fn && lf && lf[o->row],
                                             o->kind == OBJ_SN};
        if (rel != 0.0) s->time_variable = 1;
        if (b.x0 < setup->ncols && b.x0 + b.nx > 0 && b.y0 < setup->nrows && b.y0 + b.ny > 0) {
            if (o->kind == OBJ_GALAXY)
                s->stats.galaxies++, s->stats.split += pl->split > 0, s->stats.knots_smooth += o->smooth_knots;
            else if (o->kind == OBJ_STAR) s->stats.stars++;
            else s->stats.sne++;
        }
    }
    free(s->plans);
    s->plans = NULL;
    wf_renderer_config rc = {setup->ncols, setup->nrows, 0.0, sky_row, s, setup->pool_bytes, 0, halo_row,
                             s->layer_fn, s->layer_ctx, NULL, NULL, s->plane, s->layer_floor};
    if (s->plane && s->plane_found) rc.plane_get = wf_plane_entry_get;
    else if (s->plane) rc.plane_put = wf_plane_entry_put;
    if (s->plane && (st = plane_counts(s))) return st;
    s->nrobj = (size_t)kept;
    for (int t = 0; t < setup->threads; t++)
        if ((st = wf_renderer_create(&rc, s->robj, (size_t)kept, draw_object, &s->ts[t], &s->ts[t].renderer))) return st;
#ifdef __GLIBC__
    /* the set-up's large transients (pupil, PSF build) are free but still resident; hand
     * them back before the rendering fills its own buffers */
    malloc_trim(0);
#endif
    s->stats.build_seconds = now() - s->t0;
    return WF_OK;
}

wf_status wf_scene_create(const wf_scene_setup *setup, const wf_catalog *gal,
                          const wf_catalog *stars, wf_scene **out)
{
    wf_status st = wf_scene_prepare(setup, out);
    if (!st && (st = wf_scene_populate(*out, gal, stars, setup->sne, setup->nsne))) {
        wf_scene_destroy(*out);
        *out = NULL;
    }
    return st;
}

void wf_scene_destroy(wf_scene *s)
{
    if (!s) return;
    if (s->works_running) pthread_join(s->works_thread, NULL); /* it writes into s->ts */
    if (s->ts)
        for (int t = 0; t < s->setup.threads; t++) {
            wf_renderer_destroy(s->ts[t].renderer);
            if (s->ts[t].work_ready) wf_profile_work_free(&s->ts[t].work);
            free(s->ts[t].memory);
            free(s->ts[t].stamp);
        }
    free(s->ts);
    wf_plane_entry_close(s->plane);
    free(s->robj);
    free(s->plans);
    free(s->obj);
    wf_scene_psf_release(s->psf);
    free(s->area);
    free(s->bp);
    free(s);
}

wf_status wf_scene_source_for(wf_scene *s, int t, wf_scene_source *out)
{
    if (t < 0 || t >= s->setup.threads)
        return wf_error(WF_ERR_RANGE, "scene: thread %d of %d", t, s->setup.threads);
    wf_renderer_source(s->ts[t].renderer, out);
    return WF_OK;
}

void wf_scene_set_layer(wf_scene *s, const uint8_t *gal_flags, const uint8_t *star_flags,
                        void (*fn)(void *ctx, int y, const float *rates, int ncols), void *ctx, double floor)
{
    s->layer_floor = floor;
    s->layer_gal = gal_flags;
    s->layer_star = star_flags;
    s->layer_fn = fn;
    s->layer_ctx = ctx;
}

void wf_scene_set_plane(wf_scene *s, wf_plane_entry *entry, int found)
{
    s->plane = entry;
    s->plane_found = entry && found;
}

void wf_scene_get_stats(const wf_scene *s, wf_scene_stats *out) { *out = s->stats; }

size_t wf_scene_object_count(const wf_scene *s) { return s->nrobj; }

int wf_scene_time_variable(const wf_scene *s) { return s->time_variable; }

wf_status wf_scene_draw_object(wf_scene *s, size_t k, wf_scene_object *info, int *x0, int *y0,
                               int *nx, int *ny, double **pix)
{
    *pix = NULL;
    if (k >= s->nrobj) return wf_error(WF_ERR_RANGE, "scene: object %zu of %zu", k, s->nrobj);
    const wf_render_object *ro = &s->robj[k];
    const object *o = ro->data;
    /* the whole stamp as the renderer sums it: the box (kept as float), and for a split
     * galaxy its wing, negatives set to zero */
    double *buf = calloc((size_t)ro->nx * ro->ny, sizeof *buf);
    double *bx = malloc((size_t)ro->bnx * ro->bny * sizeof *bx);
    if (!buf || !bx) {
        free(buf), free(bx);
        return wf_error(WF_ERR_NOMEM, "scene: a %d x %d stamp", ro->nx, ro->ny);
    }
    float *bf = malloc((size_t)ro->bnx * ro->bny * sizeof *bf);
    wf_status st = bf ? draw_object(&s->ts[0], ro, ro->by0, ro->by0 + ro->bny, bx)
                      : wf_error(WF_ERR_NOMEM, "scene: a %d x %d box", ro->bnx, ro->bny);
    for (size_t i = 0; i < (size_t)ro->bnx * ro->bny && !st; i++) bf[i] = (float)bx[i];
    free(bx);
    if (!ro->halo) {
        for (int j = 0; j < ro->bny && !st; j++)
            for (int i = 0; i < ro->bnx; i++)
                buf[(size_t)(ro->by0 - ro->y0 + j) * ro->nx + (ro->bx0 - ro->x0) + i] =
                    bf[(size_t)j * ro->bnx + i];
    }
    int ca = ro->bx0 > ro->x0 ? ro->bx0 : ro->x0;
    int cb = ro->bx0 + ro->bnx < ro->x0 + ro->nx ? ro->bx0 + ro->bnx : ro->x0 + ro->nx;
    for (int j = 0; j < ro->ny && !st && ro->halo; j++) {
        int by = ro->y0 + j - ro->by0;
        const float *box = by >= 0 && by < ro->bny && ca < cb
                               ? bf + (size_t)by * ro->bnx + (ca - ro->bx0) : NULL;
        st = halo_row(&s->ts[0], ro, ro->y0 + j, ro->x0, ro->x0 + ro->nx, box, ca, cb,
                      buf + (size_t)j * ro->nx);
    }
    free(bf);
    if (st) { free(buf); return st; }
    info->id = object_id(s, o);
    info->kind = (int)o->kind;
    info->x = o->x;
    info->y = o->y;
    info->ra = o->ra;
    info->dec = o->dec;
    info->mag = o->mag;
    info->flux = o->flux;
    *x0 = ro->x0;
    *y0 = ro->y0;
    *nx = ro->nx;
    *ny = ro->ny;
    *pix = buf;
    return WF_OK;
}

void wf_scene_render_stats(const wf_scene *s, long *stamps, long *pieces, size_t *pool_high)
{
    *stamps = *pieces = 0;
    *pool_high = 0;
    for (int t = 0; t < s->setup.threads; t++) {
        wf_renderer_stats rs;
        wf_renderer_get_stats(s->ts[t].renderer, &rs);
        *stamps += rs.stamps_drawn;
        *pieces += rs.pieces_drawn;
        if (rs.pool_high_water > *pool_high) *pool_high = rs.pool_high_water;
    }
}

static int on_sca(const wf_scene *s, const object *o)
{
    return o->x >= -0.5 && o->y >= -0.5 && o->x < s->setup.ncols - 0.5 && o->y < s->setup.nrows - 0.5;
}

static int write_table(fitsfile *f, const wf_scene *s, obj_kind kind, const char *name, int *status)
{
    char *ttype[] = {"ID", "RA", "DEC", "X", "Y", "MAG", "FLUX", "Z", "HOSTID", "PHASE", "FLAGS"};
    char *tform[] = {"1K", "1D", "1D", "1D", "1D", "1E", "1E", "1D", "1K", "1D", "1J"};
    char *tunit[] = {"", "deg", "deg", "pixel", "pixel", "mag(AB)", "electron/s", "", "", "d", ""};
    fits_create_tbl(f, BINARY_TBL, 0, kind == OBJ_SN ? 11 : 7, ttype, tform, tunit, name, status);
    if (kind == OBJ_SN)
        fits_write_key_str(f, "PHASECNV", "rest-frame days from peak B at MJD-OBS", "PHASE", status);
    fits_write_key_str(f, "FILTER", s->setup.filter, "magnitudes and fluxes in this filter", status);
    fits_write_key_str(f, "PIXCONV", "FITS", "X, Y: 1-based pixel centres, as the image WCS", status);
    long row = 1;
    for (size_t i = 0; i < s->nobj && !*status; i++) {
        const object *o = &s->obj[i];
        if (o->kind != kind || !on_sca(s, o)) continue;
        long long id = object_id(s, o);
        double x = o->x + 1.0, y = o->y + 1.0, ra = o->ra, dec = o->dec;
        float mag = (float)o->mag, flux = (float)o->flux;
        fits_write_col(f, TLONGLONG, 1, row, 1, 1, &id, status);
        fits_write_col(f, TDOUBLE, 2, row, 1, 1, &ra, status);
        fits_write_col(f, TDOUBLE, 3, row, 1, 1, &dec, status);
        fits_write_col(f, TDOUBLE, 4, row, 1, 1, &x, status);
        fits_write_col(f, TDOUBLE, 5, row, 1, 1, &y, status);
        fits_write_col(f, TFLOAT, 6, row, 1, 1, &mag, status);
        fits_write_col(f, TFLOAT, 7, row, 1, 1, &flux, status);
        if (kind == OBJ_SN) {
            const wf_scene_sn *sn = &s->setup.sne[o->row];
            double z = sn->z, phase = sn->phase;
            long long host = sn->host_id;
            int flags = (int)sn->flags;
            fits_write_col(f, TDOUBLE, 8, row, 1, 1, &z, status);
            fits_write_col(f, TLONGLONG, 9, row, 1, 1, &host, status);
            fits_write_col(f, TDOUBLE, 10, row, 1, 1, &phase, status);
            fits_write_col(f, TINT, 11, row, 1, 1, &flags, status);
        }
        row++;
    }
    return *status;
}

wf_status wf_scene_write_truth(const wf_scene *s, const char *path, const char *digest)
{
    char tmp[2048];
    fitsfile *f;
    int status = 0;
    wf_status st = wf_fits_begin(path, tmp, sizeof tmp, &f);
    if (st) return st;
    fits_create_img(f, BYTE_IMG, 0, NULL, &status);
    fits_write_key_str(f, "FILTER", s->setup.filter, "optical element", &status);
    fits_write_key_dbl(f, "MJD-OBS", s->setup.mjd, 9, "exposure mid-time", &status);
    fits_write_key_lng(f, "SCA", s->setup.sca, "sensor chip assembly", &status);
    if (digest) fits_write_key_str(f, "WFDIGEST", digest, "inputs of the image this truth belongs to", &status);
    write_table(f, s, OBJ_GALAXY, "GALAXIES", &status);
    write_table(f, s, OBJ_STAR, "STARS", &status);
    write_table(f, s, OBJ_SN, "SNE", &status);
    /* checksums with fixed comments: the truth is byte-identical run to run */
    return wf_fits_finish(f, tmp, path, wf_fits_error(status, tmp, "writing the truth tables"));
}

wf_status wf_scene_wcs_meta(const wf_scene *s, char *buf, size_t cap)
{
    fitsfile *f;
    int status = 0;
    void *mem = NULL;
    size_t memsize = 0;
    if (fits_create_memfile(&f, &mem, &memsize, 0, realloc, &status))
        return wf_error(WF_ERR_INTERNAL, "scene: cannot open an in-memory FITS file");
    /* a header without data: with NAXIS 4088 x 4088, closing the memory file would allocate
     * and zero 67 MB for an image nobody reads (the NAXIS cards are skipped below anyway) */
    fits_create_img(f, FLOAT_IMG, 0, NULL, &status);
    wf_status st = status ? WF_ERR_INTERNAL : wf_wcs_write_header(&s->wcs, f, "in-memory header");
    size_t len = 0;
    int nkeys = 0;
    fits_get_hdrspace(f, &nkeys, NULL, &status);
    len += (size_t)snprintf(buf, cap, "img.WCSAXES = 2 / WCS applies to the image plane\n");
    for (int k = 1; k <= nkeys && !status && !st; k++) {
        char card[FLEN_CARD], key[FLEN_KEYWORD], value[FLEN_VALUE], comment[FLEN_COMMENT];
        int kl = 0;
        fits_read_record(f, k, card, &status);
        fits_get_keyname(card, key, &kl, &status);
        if (!strcmp(key, "SIMPLE") || !strcmp(key, "BITPIX") || !strncmp(key, "NAXIS", 5) ||
            !strcmp(key, "EXTEND") || !strcmp(key, "COMMENT") || !strcmp(key, "WCSAXES"))
            continue;
        fits_parse_value(card, value, comment, &status);
        int n = snprintf(buf + len, len < cap ? cap - len : 0, "img.%s = %s%s%s\n", key, value,
                         comment[0] ? " / " : "", comment);
        if (n < 0 || len + (size_t)n >= cap) { st = wf_error(WF_ERR_RANGE, "scene: WCS cards exceed %zu bytes", cap); break; }
        len += (size_t)n;
    }
    int cs = 0;
    fits_close_file(f, &cs);
    free(mem);
    if (!st && status) st = wf_error(WF_ERR_INTERNAL, "scene: cfitsio status %d on the WCS header", status);
    return st;
}
