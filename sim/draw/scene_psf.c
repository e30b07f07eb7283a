#include "sim/draw/scene_psf.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "hal/arena.h"
#include "sim/optics/bandpass.h"
#include "sim/optics/psf.h"

/* Every input of the PSF and its tables, and all that build() reads of a scene's setup (its
 * thread count aside, which changes no bit): two scenes that agree on these get the same
 * bits. */
typedef struct psf_key {
    char filter[16];
    char data_dir[1024];
    int sca, pupil_bin, psf_oversample, psf_size, psf_nlambda, core_levels;
    double jitter, diffusion, flux_fraction, core_radius;
} psf_key;

struct wf_scene_psf_private {
    psf_key key;
    int threads;                  /* for building the tables (the same for any count) */
    wf_profile_accuracy acc;      /* the tables' knobs (key_accuracy) */
    wf_psf_optics optics;         /* the wide PSF is built from these */
    double lams[WF_PSF_MAX_LAMBDAS], ws[WF_PSF_MAX_LAMBDAS];
    int nl;
    double band_limit;
    void *memory, *wide_memory;   /* the tables' arenas */
    int refs;                     /* scenes holding it */
    int cached;                   /* in cache's list (else freed with its last release) */
    unsigned long used;           /* cache's clock when last taken */
    wf_scene_psf_cache *cache;    /* while cached */
};

struct wf_scene_psf_cache {
    int capacity, n;
    wf_scene_psf **e;
    unsigned long clock;
    wf_scene_psf_cache_stats stats;
};

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static void key_of(const wf_scene_setup *s, psf_key *k)
{
    memset(k, 0, sizeof *k);
    snprintf(k->filter, sizeof k->filter, "%s", s->filter);
    snprintf(k->data_dir, sizeof k->data_dir, "%s", s->data_dir);
    k->sca = s->sca;
    k->pupil_bin = s->pupil_bin;
    k->psf_oversample = s->psf_oversample;
    k->psf_size = s->psf_size;
    k->psf_nlambda = s->psf_nlambda;
    k->core_levels = s->core_levels;
    k->jitter = s->jitter;
    k->diffusion = s->diffusion;
    k->flux_fraction = s->flux_fraction;
    k->core_radius = s->core_radius;
}

static void key_accuracy(const psf_key *k, wf_profile_accuracy *acc)
{
    wf_profile_accuracy_default(acc);
    acc->flux_fraction = k->flux_fraction;
    acc->core_radius = k->core_radius;
    acc->core_levels = k->core_levels;
}

void wf_scene_psf_accuracy(const wf_scene_setup *setup, wf_profile_accuracy *acc)
{
    psf_key k;
    key_of(setup, &k);
    key_accuracy(&k, acc);
}

static int key_same(const psf_key *a, const psf_key *b)
{
    return !strcmp(a->filter, b->filter) && !strcmp(a->data_dir, b->data_dir) && a->sca == b->sca &&
           a->pupil_bin == b->pupil_bin && a->psf_oversample == b->psf_oversample && a->psf_size == b->psf_size &&
           a->psf_nlambda == b->psf_nlambda && a->core_levels == b->core_levels && a->jitter == b->jitter &&
           a->diffusion == b->diffusion && a->flux_fraction == b->flux_fraction && a->core_radius == b->core_radius;
}

/* The tables sit at the bottom of their block; the transforms that computed them used the
 * rest, which nothing reads again: hand those pages back so they do not stay resident. */
static void release_tail(const wf_arena *a)
{
    long page = sysconf(_SC_PAGESIZE);
    if (page <= 0) return;
    uintptr_t start = ((uintptr_t)a->base + a->used + (uintptr_t)page - 1) & ~((uintptr_t)page - 1);
    uintptr_t end = ((uintptr_t)a->base + a->capacity) & ~((uintptr_t)page - 1);
    if (end > start) (void)madvise((void *)start, end - start, MADV_DONTNEED);
}

/* An image of side n at the key's sampling from optics, normalised to unit sum (*sum: its sum
 * before); the image is what the tables are made from, so the optics' coefficients go at once. */
static wf_status draw_image(const wf_psf_optics *optics, const struct wf_scene_psf_private *q, int n,
                            double *pix, double *sum)
{
    wf_psf *psf;
    wf_status st = wf_psf_build_optics(optics, q->lams, q->ws, q->nl, &psf);
    if (st) return st;
    wf_psf_draw_opts d;
    wf_psf_draw_opts_default(&d);
    d.nx = d.ny = n;
    d.scale = WF_PSF_PIXEL_SCALE / q->key.psf_oversample;
    d.cx = d.cy = (n - 1) / 2.0;
    d.pixel = 0; /* the drawer applies the pixel */
    d.jitter = q->key.jitter;
    d.diffusion = q->key.diffusion;
    d.threads = q->threads;
    /* the wide image by chirp-z transforms: only its samples, at its scale (~0.5 -> ~0.03
     * CPU-s); ~4e-15 of the peak from the direct sum, which left every product pixel the same
     * (docs/BENCHMARKS.md) */
    d.czt = n > q->key.psf_size;
    st = wf_psf_draw(psf, &d, pix);
    wf_psf_free(psf);
    if (st) return st;
    double psum = 0.0;
    for (size_t k = 0; k < (size_t)n * n; k++) psum += pix[k];
    for (size_t k = 0; k < (size_t)n * n; k++) pix[k] /= psum;
    *sum = psum;
    return WF_OK;
}

/* The tables of image img under acc, on up to `threads` threads, in memory of their own. */
static wf_status make_tables(const wf_psf_image *img, const wf_profile_accuracy *acc, int threads, const char *name,
                             void **memory, wf_profile_psf *out)
{
    size_t keep, scratch;
    wf_status st = wf_profile_psf_need(img, acc, &keep, &scratch);
    if (st) return st;
    size_t bytes = keep + (size_t)threads * (scratch + 64) + 4096;
    if (!(*memory = wf_arena_host_alloc(bytes))) return wf_error(WF_ERR_NOMEM, "scene: %s of %zu bytes", name, bytes);
    wf_arena arena;
    wf_arena_init(&arena, *memory, bytes, name);
    if ((st = wf_profile_psf_init(out, img, acc, &arena, threads))) return st;
    release_tail(&arena);
    return WF_OK;
}

static void psf_free(wf_scene_psf *p)
{
    if (!p) return;
    if (p->priv) {
        free(p->priv->memory);
        free(p->priv->wide_memory);
    }
    free(p->priv);
    free(p);
}

/* PSF: this SCA and filter only; achromatic at the band's effective wavelength, or the
 * photon-weighted sum over slices of the band for a flat-f_nu source. From the key alone. */
static wf_status build(const psf_key *key, int threads, wf_scene_psf **out)
{
    wf_scene_psf *p = calloc(1, sizeof *p);
    struct wf_scene_psf_private *q = p ? calloc(1, sizeof *q) : NULL;
    wf_bandpass *bp = q ? malloc(sizeof *bp) : NULL;
    if (!bp) {
        free(q);
        free(p);
        return wf_error(WF_ERR_NOMEM, "scene: out of memory");
    }
    p->priv = q;
    q->key = *key;
    wf_status st;
    wf_filter filter;
    wf_psf_optics_default(&q->optics);
    q->optics.sca = key->sca;
    q->optics.pupil_bin = key->pupil_bin;
    double *pix = NULL;
    const char *data = key->data_dir[0] ? key->data_dir : NULL;
    if ((st = wf_filter_parse(key->filter, &filter)) || (st = wf_bandpass_load(filter, data, bp))) goto bad;
    if ((st = wf_pupil_group_of_filter(key->filter, &q->optics.group))) goto bad;
    snprintf(q->optics.data_dir, sizeof q->optics.data_dir, "%s", key->data_dir);
    int nl = key->psf_nlambda;
    if (nl < 1 || nl > WF_PSF_MAX_LAMBDAS) {
        st = wf_error(WF_ERR_RANGE, "scene: psf nlambda %d outside 1..%d", nl, WF_PSF_MAX_LAMBDAS);
        goto bad;
    }
    if (!(key->jitter >= 0) || !(key->diffusion >= 0)) {
        st = wf_error(WF_ERR_RANGE, "scene: jitter %g arcsec and diffusion %g pixels must be >= 0", key->jitter,
                      key->diffusion);
        goto bad;
    }
    if (nl == 1) {
        q->lams[0] = bp->lambda_eff_nm, q->ws[0] = 1.0;
    } else if ((st = wf_bandpass_flat_slices(bp, nl, q->lams, q->ws))) {
        goto bad;
    }
    q->nl = nl;
    double lam = q->lams[0], lam_mean = 0.0;
    for (int k = 0; k < nl; k++) {
        lam_mean += q->ws[k] * q->lams[k];
        if (q->lams[k] < lam) lam = q->lams[k]; /* the bluest slice sets the band limit */
    }
    p->lambda_nm = lam_mean;
    /* the pupil's cut-off 2 pi D / lambda in rad/arcsec: D = 2.36 m (SPEC §2) */
    q->band_limit = 2.0 * M_PI * 2.36 / (lam * 1e-9) * (M_PI / (180.0 * 3600.0));
    key_accuracy(key, &q->acc);
    /* the cores' tables on up to one thread each (scratch for each, given back at once) */
    const int cores = q->acc.core_radius > 0.0 ? q->acc.core_levels : 1;
    q->threads = threads < 1 ? 1 : threads;
    const int pt = q->threads < cores ? q->threads : cores;
    int n = key->psf_size;
    if (!(pix = wf_arena_host_realloc(NULL, 0, (size_t)n * n * sizeof *pix))) {
        st = wf_error(WF_ERR_NOMEM, "scene: PSF image");
        goto bad;
    }
    /* The image holds ~99% of the light within its 7" (the rest is far wings and spikes);
     * normalised, every object keeps its whole flux, the wings' share moved inside. */
    if ((st = draw_image(&q->optics, q, n, pix, &p->image_sum))) goto bad;
    const wf_psf_image img = {n, WF_PSF_PIXEL_SCALE / key->psf_oversample, pix, q->band_limit};
    if ((st = make_tables(&img, &q->acc, pt, "scene PSF arena", &q->memory, &p->ppsf))) goto bad;
    free(pix); /* the tables are all the drawer reads */
    free(bp);
    q->refs = 1;
    *out = p;
    return WF_OK;
bad:
    free(pix);
    free(bp);
    psf_free(p);
    return st;
}

/* The wide PSF of bright point sources: four times the image side (28" at the default
 * sampling), from a pupil binned no coarser than 4 so that its period (46" at Y106) holds the
 * image, with a PSF table whose period is the image's width (the halo does not fold).
 * Normalised like the narrow one. */
wf_status wf_scene_psf_wide(wf_scene_psf *p)
{
    if (p->wide_built) return WF_OK;
    double t0 = now();
    struct wf_scene_psf_private *q = p->priv;
    wf_psf_optics optics = q->optics;
    if (optics.pupil_bin > 4) optics.pupil_bin = 4;
    int n = 4 * q->key.psf_size;
    double *pix = malloc((size_t)n * n * sizeof *pix), sum;
    if (!pix) return wf_error(WF_ERR_NOMEM, "scene: wide PSF image of %d x %d", n, n);
    wf_status st = draw_image(&optics, q, n, pix, &sum);
    const wf_psf_image img = {n, WF_PSF_PIXEL_SCALE / q->key.psf_oversample, pix, q->band_limit};
    wf_profile_accuracy acc = q->acc;
    acc.core_radius = 0.0; /* few objects; their halo is what they are drawn for */
    /* the table's period is the image's width: the image periodised onto it does not overlap
     * itself, and a wider period would only cost memory (the transform of os x period) */
    acc.psf_table_fft = 2 * (int)ceil(n / (double)q->key.psf_oversample / 2.0);
    acc.extra_tables = 0; /* a few stars, whose boxes are near that period anyway */
    if (!st) st = make_tables(&img, &acc, 1, "scene wide PSF arena", &q->wide_memory, &p->ppsf_wide);
    free(pix);
    if (st) {
        free(q->wide_memory);
        q->wide_memory = NULL;
        return st;
    }
    p->wide_built = 1;
    p->wide_seconds = now() - t0;
    if (q->cached) q->cache->stats.wide_built++;
    return WF_OK;
}

wf_status wf_scene_psf_cache_new(int capacity, wf_scene_psf_cache **out)
{
    *out = NULL;
    if (capacity < 1) return wf_error(WF_ERR_RANGE, "scene PSF cache: capacity %d below 1", capacity);
    wf_scene_psf_cache *c = calloc(1, sizeof *c);
    if (!c || !(c->e = calloc((size_t)capacity, sizeof *c->e))) {
        free(c);
        return wf_error(WF_ERR_NOMEM, "scene PSF cache: out of memory");
    }
    c->capacity = capacity;
    *out = c;
    return WF_OK;
}

/* Out of the list; freed now unless a scene holds it. */
static void drop(wf_scene_psf_cache *c, int i)
{
    wf_scene_psf *p = c->e[i];
    p->priv->cached = 0;
    p->priv->cache = NULL;
    if (!p->priv->refs) psf_free(p);
    c->e[i] = c->e[--c->n];
}

void wf_scene_psf_cache_free(wf_scene_psf_cache *c)
{
    if (!c) return;
    while (c->n) drop(c, c->n - 1);
    free(c->e);
    free(c);
}

void wf_scene_psf_cache_get_stats(const wf_scene_psf_cache *c, wf_scene_psf_cache_stats *out)
{
    *out = c->stats;
}

wf_status wf_scene_psf_get(wf_scene_psf_cache *cache, const wf_scene_setup *setup, wf_scene_psf **out)
{
    *out = NULL;
    psf_key key;
    key_of(setup, &key);
    if (cache)
        for (int i = 0; i < cache->n; i++)
            if (key_same(&cache->e[i]->priv->key, &key)) {
                wf_scene_psf *p = cache->e[i];
                p->priv->refs++;
                p->priv->used = ++cache->clock;
                cache->stats.reused++;
                *out = p;
                return WF_OK;
            }
    if (cache && cache->n == cache->capacity) { /* the least recently taken makes room first:
                                                 * the cache holds no more than capacity (a
                                                 * scene may still hold the one it let go) */
        int old = 0;
        for (int i = 1; i < cache->n; i++)
            if (cache->e[i]->priv->used < cache->e[old]->priv->used) old = i;
        drop(cache, old);
    }
    wf_scene_psf *p = NULL;
    wf_status st = build(&key, setup->threads, &p);
    if (st) return st;
    if (cache) {
        cache->e[cache->n++] = p;
        p->priv->cached = 1;
        p->priv->cache = cache;
        p->priv->used = ++cache->clock;
        cache->stats.built++;
    }
    *out = p;
    return WF_OK;
}

wf_status wf_scene_psf_prefetch(const wf_scene_setup *setup, int wide)
{
    if (!setup->psf_cache) return wf_error(WF_ERR_INPUT, "scene PSF prefetch: no cache");
    wf_scene_psf *p = NULL;
    wf_status st = wf_scene_psf_get(setup->psf_cache, setup, &p);
    if (!st && wide) st = wf_scene_psf_wide(p);
    wf_scene_psf_release(p);
    return st;
}

void wf_scene_psf_release(wf_scene_psf *p)
{
    if (!p) return;
    if (--p->priv->refs == 0 && !p->priv->cached) psf_free(p);
}
