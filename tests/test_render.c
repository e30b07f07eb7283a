/* The tile renderer with an analytic Gaussian stamp: output independent of tile height and
 * pool size, flux conserved, objects off the SCA never drawn, crowded and empty tiles; objects
 * that keep only a box in the pool and add a halo row by row. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sim/draw/render.h"
#include "tests/testutil.h"

typedef struct gauss { double x, y, sigma, flux, halo_sigma, halo_flux; } gauss;
typedef struct counter { long calls; long rows; } counter;

static double frac(int i, double c, double s)
{
    double k = 1.0 / (M_SQRT2 * s);
    return 0.5 * (erf((i + 0.5 - c) * k) - erf((i - 0.5 - c) * k));
}

static wf_status draw_gauss(void *ctx, const wf_render_object *o, int ya, int yb, double *out)
{
    counter *c = ctx;
    const gauss *g = o->data;
    c->calls++;
    c->rows += yb - ya;
    for (int y = ya; y < yb; y++) { /* the box (the whole footprint unless set) */
        double fy = g->flux * frac(y, g->y, g->sigma);
        for (int i = 0; i < o->bnx; i++) out[(size_t)(y - ya) * o->bnx + i] = fy * frac(o->bx0 + i, g->x, g->sigma);
    }
    return WF_OK;
}

enum { HALO_MAX = 512 }; /* the widest footprint row the tests draw */

/* What a halo function must do with the halo's row (halo[x - xa]) and the box's pixels the
 * renderer hands it: sum, clip, add. The box columns must lie within the row's. */
static void add_box_halo(int xa, int xb, const float *box, int ca, int cb, const double *halo,
                         double *acc)
{
    if (box) ck_assert(xa <= ca && ca < cb && cb <= xb);
    for (int x = xa; x < xb; x++) {
        double v = (box && x >= ca && x < cb ? (double)box[x - ca] : 0.0) + halo[x - xa];
        acc[x - xa] += v < 0.0 ? 0.0 : v;
    }
}

/* The wider Gaussian of a halo object, added over the footprint. */
static wf_status halo_gauss(void *ctx, const wf_render_object *o, int y, int xa, int xb,
                            const float *box, int ca, int cb, double *acc)
{
    (void)ctx;
    const gauss *g = o->data;
    double fy = g->halo_flux * frac(y, g->y, g->halo_sigma), halo[HALO_MAX];
    ck_assert_int_le(xb - xa, HALO_MAX);
    for (int x = xa; x < xb; x++) halo[x - xa] = fy * frac(x, g->x, g->halo_sigma);
    add_box_halo(xa, xb, box, ca, cb, halo, acc);
    return WF_OK;
}

static void make_objects(int n, int ncols, int nrows, gauss *g, wf_render_object *o, unsigned seed)
{
    srand(seed);
    for (int i = 0; i < n; i++) {
        g[i].x = -20.0 + (ncols + 40.0) * rand() / (double)RAND_MAX; /* some off the edges */
        g[i].y = -20.0 + (nrows + 40.0) * rand() / (double)RAND_MAX;
        g[i].sigma = 0.5 + 4.0 * rand() / (double)RAND_MAX;
        g[i].flux = 10.0 + 1000.0 * rand() / (double)RAND_MAX;
        int h = (int)ceil(6 * g[i].sigma);
        o[i] = (wf_render_object){(uint64_t)i, (int)floor(g[i].x) - h, (int)floor(g[i].y) - h, 2 * h + 2, 2 * h + 2, &g[i], 0.0, 0, 0, 0, 0, 0, 0, 0};
    }
}

/* Rates for the whole SCA, asked for as the firmware does: tiles with one halo row. */
static float *render_all(const wf_renderer_config *cfg, const wf_render_object *o, int n, int tile,
                         counter *c)
{
    wf_renderer *r;
    ck_assert_int_eq(wf_renderer_create(cfg, o, (size_t)n, draw_gauss, c, &r), WF_OK);
    wf_scene_source src;
    wf_renderer_source(r, &src);
    float *img = calloc((size_t)cfg->ncols * cfg->nrows, sizeof *img);
    float *buf = malloc((size_t)(tile + 2) * cfg->ncols * sizeof *buf);
    for (int y0 = 0; y0 < cfg->nrows; y0 += tile) {
        int y1 = y0 + tile < cfg->nrows ? y0 + tile : cfg->nrows;
        int h0 = y0 ? y0 - 1 : 0, h1 = y1 < cfg->nrows ? y1 + 1 : y1;
        ck_assert_int_eq(wf_scene_fill(&src, h0, h1, cfg->ncols, buf), WF_OK);
        for (int y = h0; y < h1; y++) {
            float *row = img + (size_t)y * cfg->ncols, *got = buf + (size_t)(y - h0) * cfg->ncols;
            if (y >= y0 && y < y1) memcpy(row, got, (size_t)cfg->ncols * sizeof *row);
            else ck_assert_msg(!memcmp(row, got, (size_t)cfg->ncols * sizeof *row) || y >= y1,
                               "halo row %d differs between tiles", y);
        }
    }
    free(buf);
    wf_renderer_destroy(r);
    return img;
}

START_TEST(tile_height_and_pool_do_not_matter)
{
    enum { N = 400, W = 120, H = 150 };
    static gauss g[N];
    static wf_render_object o[N];
    make_objects(N, W, H, g, o, 7);
    wf_renderer_config cfg = {W, H, 0.4, NULL, NULL, 1u << 22, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    float *ref = render_all(&cfg, o, N, H, &c);
    const int tiles[] = {1, 7, 64};
    for (int t = 0; t < 3; t++) {
        float *img = render_all(&cfg, o, N, tiles[t], &c);
        ck_assert_msg(!memcmp(ref, img, sizeof(float) * W * H), "tile height %d changes the rates", tiles[t]);
        free(img);
    }
    /* a pool too small for most stamps: drawn in pieces, same numbers */
    cfg.pool_bytes = 2000;
    float *small = render_all(&cfg, o, N, 7, &c);
    ck_assert_msg(!memcmp(ref, small, sizeof(float) * W * H), "piecewise drawing changes the rates");
    free(small);
    free(ref);
}
END_TEST

/* Objects made of a core kept in a box and a halo three times wider over the footprint: the
 * same image whatever the tile height and pool (pieces), and the flux of both parts within
 * the SCA to 1e-6 (float rates). */
START_TEST(halo_objects)
{
    enum { N = 150, W = 100, H = 120 };
    static gauss g[N];
    static wf_render_object o[N];
    make_objects(N, W, H, g, o, 11);
    double total = 0.0;
    for (int i = 0; i < N; i++) {
        g[i].halo_sigma = 3.0 * g[i].sigma;
        g[i].halo_flux = 0.05 * g[i].flux;
        int hb = (int)ceil(6 * g[i].sigma), hf = (int)ceil(6 * g[i].halo_sigma);
        o[i].x0 = (int)floor(g[i].x) - hf, o[i].y0 = (int)floor(g[i].y) - hf;
        o[i].nx = o[i].ny = 2 * hf + 2;
        o[i].bx0 = (int)floor(g[i].x) - hb, o[i].by0 = (int)floor(g[i].y) - hb;
        o[i].bnx = o[i].bny = 2 * hb + 2;
        o[i].halo = 1;
    }
    wf_renderer_config cfg = {W, H, 0.0, NULL, NULL, 1u << 22, 0, halo_gauss, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    float *ref = render_all(&cfg, o, N, H, &c);
    const int tiles[] = {1, 9, 40};
    for (int t = 0; t < 3; t++) {
        float *img = render_all(&cfg, o, N, tiles[t], &c);
        ck_assert_msg(!memcmp(ref, img, sizeof(float) * W * H), "tile height %d changes the rates", tiles[t]);
        free(img);
    }
    cfg.pool_bytes = 3000;
    float *small = render_all(&cfg, o, N, 7, &c);
    ck_assert_msg(!memcmp(ref, small, sizeof(float) * W * H), "pieces change the rates");
    free(small);
    /* flux: every part of every object inside the SCA */
    for (int i = 0; i < N; i++) {
        double fx = 0, fy = 0, hx = 0, hy = 0;
        for (int x = 0; x < W; x++) {
            if (x >= o[i].bx0 && x < o[i].bx0 + o[i].bnx) fx += frac(x, g[i].x, g[i].sigma);
            if (x >= o[i].x0 && x < o[i].x0 + o[i].nx) hx += frac(x, g[i].x, g[i].halo_sigma);
        }
        for (int y = 0; y < H; y++) {
            if (y >= o[i].by0 && y < o[i].by0 + o[i].bny) fy += frac(y, g[i].y, g[i].sigma);
            if (y >= o[i].y0 && y < o[i].y0 + o[i].ny) hy += frac(y, g[i].y, g[i].halo_sigma);
        }
        total += g[i].flux * fx * fy + g[i].halo_flux * hx * hy;
    }
    double sum = 0.0;
    for (int k = 0; k < W * H; k++) sum += ref[k];
    ck_assert_msg(fabs(sum / total - 1) < 1e-6, "flux %.8g of %.8g", sum, total);
    free(ref);
}
END_TEST

/* A halo that goes negative where the box's light has ended: each pixel is the box (as
 * float) plus the halo, set to zero where the sum is negative. */
static wf_status halo_dip(void *ctx, const wf_render_object *o, int y, int xa, int xb,
                          const float *box, int ca, int cb, double *acc)
{
    (void)ctx;
    const gauss *g = o->data;
    double halo[HALO_MAX];
    ck_assert_int_le(xb - xa, HALO_MAX);
    for (int x = xa; x < xb; x++) halo[x - xa] = g->halo_flux * (fabs(x - g->x) + fabs(y - g->y) - 8.0);
    add_box_halo(xa, xb, box, ca, cb, halo, acc);
    return WF_OK;
}

START_TEST(halo_clipped)
{
    enum { W = 40, H = 30 };
    static gauss g[1] = {{20.3, 14.6, 1.2, 500.0, 0.0, 0.5}};
    wf_render_object o = {1, 5, 2, 30, 26, &g[0], 0.0, 1, 15, 10, 12, 10, 0, 0};
    wf_renderer_config cfg = {W, H, 0.0, NULL, NULL, 1u << 20, 0, halo_dip, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    float *img = render_all(&cfg, &o, 1, 7, &c);
    int zero = 0, positive_halo = 0;
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double box = 0.0, halo = 0.0;
            if (x >= o.x0 && x < o.x0 + o.nx && y >= o.y0 && y < o.y0 + o.ny)
                halo = g[0].halo_flux * (fabs(x - g[0].x) + fabs(y - g[0].y) - 8.0);
            else { ck_assert(img[y * W + x] == 0.0f); continue; }
            if (x >= o.bx0 && x < o.bx0 + o.bnx && y >= o.by0 && y < o.by0 + o.bny)
                box = (float)(g[0].flux * frac(y, g[0].y, g[0].sigma) * frac(x, g[0].x, g[0].sigma));
            double want = box + halo < 0.0 ? 0.0 : box + halo;
            ck_assert_msg(img[y * W + x] == (float)want, "pixel (%d, %d): %.9g, expected %.9g", x, y,
                          img[y * W + x], want);
            zero += want == 0.0;
            positive_halo += halo > 0.0 && box == 0.0;
        }
    ck_assert(zero > 10 && positive_halo > 10); /* both branches were exercised */
    free(img);
}
END_TEST

/* Objects may hand over negative pixels (the scene's draws keep their ringing, so that
 * none adds flux): the renderer adds them as they are and clips only the sum, sky
 * included, at zero. A positive and a negative object overlapping on a sky of 1. */
static wf_status draw_const(void *ctx, const wf_render_object *o, int ya, int yb, double *out)
{
    (void)ctx;
    const double v = *(const double *)o->data;
    for (size_t i = 0; i < (size_t)(yb - ya) * o->bnx; i++) out[i] = v;
    return WF_OK;
}

START_TEST(negatives_clipped_in_the_sum)
{
    enum { W = 30, H = 20 };
    static double val[2] = {5.0, -3.0};
    wf_render_object o[2] = {{1, 2, 3, 12, 10, &val[0], 0.0, 0, 0, 0, 0, 0, 0, 0},
                             {2, 8, 6, 15, 9, &val[1], 0.0, 0, 0, 0, 0, 0, 0, 0}};
    wf_renderer_config cfg = {W, H, 1.0, NULL, NULL, 1u << 20, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    wf_renderer *r;
    ck_assert_int_eq(wf_renderer_create(&cfg, o, 2, draw_const, NULL, &r), WF_OK);
    wf_scene_source src;
    wf_renderer_source(r, &src);
    float img[W * H];
    ck_assert_int_eq(wf_scene_fill(&src, 0, H, W, img), WF_OK);
    int seen[3] = {0, 0, 0};
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            double want = 1.0;
            for (int k = 0; k < 2; k++)
                if (x >= o[k].x0 && x < o[k].x0 + o[k].nx && y >= o[k].y0 && y < o[k].y0 + o[k].ny) want += val[k];
            seen[want == 3.0 ? 0 : want < 0.0 ? 1 : 2]++;
            if (want < 0.0) want = 0.0;
            ck_assert_msg(img[y * W + x] == (float)want, "pixel (%d, %d): %g, expected %g", x, y, img[y * W + x], want);
        }
    ck_assert(seen[0] > 0 && seen[1] > 0); /* the overlap (1 + 5 - 3) and the clipped part */
    wf_renderer_destroy(r);
}
END_TEST

START_TEST(flux_conserved_and_off_sca_skipped)
{
    enum { N = 300, W = 100, H = 90 };
    static gauss g[N];
    static wf_render_object o[N];
    make_objects(N, W, H, g, o, 11);
    /* three objects entirely off the SCA */
    o[0].x0 = W + 5;
    o[1].y0 = -o[1].ny - 3;
    o[2].x0 = -o[2].nx;
    wf_renderer_config cfg = {W, H, 0.25, NULL, NULL, 1u << 22, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    wf_renderer *r;
    ck_assert_int_eq(wf_renderer_create(&cfg, o, N, draw_gauss, &c, &r), WF_OK);
    wf_renderer_stats st;
    wf_renderer_get_stats(r, &st);
    int expect_skipped = 3;
    for (int i = 3; i < N; i++)
        if (o[i].x0 >= W || o[i].x0 + o[i].nx <= 0 || o[i].y0 >= H || o[i].y0 + o[i].ny <= 0) expect_skipped++;
    ck_assert_int_eq(st.objects_skipped, expect_skipped);
    wf_renderer_destroy(r);
    float *img = render_all(&cfg, o, N, 16, &c);
    double sum = 0, expect = 0.25 * W * H;
    for (int i = 0; i < W * H; i++) sum += img[i];
    for (int i = 3; i < N; i++) {
        if (o[i].x0 >= W || o[i].x0 + o[i].nx <= 0 || o[i].y0 >= H || o[i].y0 + o[i].ny <= 0) continue;
        double fx = 0, fy = 0; /* the part of the stamp that lies on the SCA */
        for (int x = o[i].x0 > 0 ? o[i].x0 : 0; x < o[i].x0 + o[i].nx && x < W; x++) fx += frac(x, g[i].x, g[i].sigma);
        for (int y = o[i].y0 > 0 ? o[i].y0 : 0; y < o[i].y0 + o[i].ny && y < H; y++) fy += frac(y, g[i].y, g[i].sigma);
        expect += g[i].flux * fx * fy;
    }
    ck_assert_msg(fabs(sum - expect) < 1e-6 * expect, "sum %.6f, expected %.6f", sum, expect);
    free(img);
}
END_TEST

START_TEST(crowded_tile_and_empty_scene)
{
    enum { N = 10000, W = 256, H = 64 };
    gauss *g = malloc(N * sizeof *g);
    wf_render_object *o = malloc(N * sizeof *o);
    make_objects(N, W, 8, g, o, 3); /* 10,000 objects on the first rows */
    wf_renderer_config cfg = {W, H, 0.0, NULL, NULL, 1u << 24, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    float *img = render_all(&cfg, o, N, 64, &c);
    double sum = 0;
    for (int i = 0; i < W * H; i++) {
        ck_assert(isfinite(img[i]) && img[i] >= 0.0f);
        sum += img[i];
    }
    ck_assert(sum > 0);
    ck_assert_msg(c.calls <= N, "%ld draws for %d objects", c.calls, N);
    free(img);
    /* empty: the sky and nothing else */
    wf_renderer_config e = {W, H, 1.5, NULL, NULL, 0, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    float *sky = render_all(&e, NULL, 0, 16, &c);
    for (int i = 0; i < W * H; i++) ck_assert(sky[i] == 1.5f);
    free(sky);
    free(g);
    free(o);
}
END_TEST

START_TEST(each_stamp_drawn_once)
{
    enum { N = 200, W = 80, H = 200 };
    static gauss g[N];
    static wf_render_object o[N];
    make_objects(N, W, H, g, o, 5);
    wf_renderer_config cfg = {W, H, 0.0, NULL, NULL, 1u << 24, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    wf_renderer *r;
    ck_assert_int_eq(wf_renderer_create(&cfg, o, N, draw_gauss, &c, &r), WF_OK);
    wf_renderer_stats st;
    wf_renderer_get_stats(r, &st);
    wf_renderer_destroy(r);
    c.calls = 0;
    float *img = render_all(&cfg, o, N, 4, &c);
    ck_assert_msg(c.calls == st.objects_kept, "%ld draws for %ld objects on the SCA", c.calls, st.objects_kept);
    free(img);
}
END_TEST

/* The pool is used up to about twice the live stamps before it is compacted, not to its
 * end: the pages a bump allocation reaches are resident memory. 4,000 stamps (~60 MB drawn in
 * all) pass through a 64 MiB pool whose live set is a few hundred kB. */
START_TEST(pool_kept_near_live_stamps)
{
    enum { N = 4000, W = 80, H = 20000 };
    static gauss g[N];
    static wf_render_object o[N];
    make_objects(N, W, H, g, o, 9);
    const size_t mib = (size_t)1 << 20;
    wf_renderer_config cfg = {W, H, 0.0, NULL, NULL, 64 * mib, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    wf_renderer *r;
    ck_assert_int_eq(wf_renderer_create(&cfg, o, N, draw_gauss, &c, &r), WF_OK);
    wf_scene_source src;
    wf_renderer_source(r, &src);
    float *buf = malloc((size_t)16 * W * sizeof *buf);
    for (int y0 = 0; y0 < H; y0 += 16) ck_assert_int_eq(wf_scene_fill(&src, y0, y0 + 16, W, buf), WF_OK);
    wf_renderer_stats st;
    wf_renderer_get_stats(r, &st);
    wf_renderer_destroy(r);
    free(buf);
    size_t drawn = 0, largest = 0;
    for (int i = 0; i < N; i++) {
        size_t px = (size_t)o[i].nx * (size_t)o[i].ny; /* the box is the footprint here */
        drawn += px * sizeof(float);                     /* kept as float */
        if (px * sizeof(double) > largest) largest = px * sizeof(double); /* drawn in double */
    }
    ck_assert_uint_gt(drawn, 16 * mib); /* the pool would otherwise fill to that */
    ck_assert_uint_eq((size_t)st.stamps_drawn, (size_t)c.calls);
    size_t bound = 2 * (st.live_high_water + largest);
    if (bound < 4 * mib) bound = 4 * mib;
    ck_assert_msg(st.pool_high_water <= bound + largest, "pool used to %zu bytes, live at most %zu",
                  st.pool_high_water, st.live_high_water);
}
END_TEST

/* A stamp's rows the tiles have passed leave the pool: a chain of tall stamps, each starting
 * 60 rows below the previous one, in a pool that holds one whole stamp plus the next one's
 * double-precision draw only once the first has lost its passed rows (100 x 50 floats are
 * 20,000 bytes, the next draw 40,000, the pool 56,000: room for 80 rows of the first, which
 * a tile of up to 40 rows that reaches row 60 has passed). Kept whole, every stamp after the
 * first was drawn in pieces, one per tile; now each is drawn once, whole, and the rates are
 * those of a pool large enough for all of them, whatever the tile height. */
START_TEST(passed_rows_leave_the_pool)
{
    enum { N = 12, W = 70, H = 60 * N + 60, NY = 100, NX = 50 };
    static gauss g[N];
    static wf_render_object o[N];
    for (int i = 0; i < N; i++) {
        g[i] = (gauss){12.0 + 0.5 * NX + 0.37 * i, 60.0 * i + 0.5 * NY + 0.21 * i, 9.0 + 0.3 * i, 1000.0 + i, 0, 0};
        o[i] = (wf_render_object){(uint64_t)i, 12 + (i % 3), 60 * i, NX, NY, &g[i], 0.0, 0, 0, 0, 0, 0, 0, 0};
    }
    wf_renderer_config big = {W, H, 0.1, NULL, NULL, 1u << 22, 0, NULL, NULL, NULL, NULL, NULL, NULL, 0.0};
    counter c = {0, 0};
    float *ref = render_all(&big, o, N, 10, &c);
    wf_renderer_config cfg = big;
    cfg.pool_bytes = 56000;
    const int tiles[] = {10, 1, 7, 33, 40};
    for (int t = 0; t < 5; t++) {
        wf_renderer *r;
        c = (counter){0, 0};
        ck_assert_int_eq(wf_renderer_create(&cfg, o, N, draw_gauss, &c, &r), WF_OK);
        wf_scene_source src;
        wf_renderer_source(r, &src);
        float *img = malloc((size_t)W * H * sizeof *img);
        for (int y0 = 0; y0 < H; y0 += tiles[t]) {
            int y1 = y0 + tiles[t] < H ? y0 + tiles[t] : H;
            ck_assert_int_eq(wf_scene_fill(&src, y0, y1, W, img + (size_t)y0 * W), WF_OK);
        }
        wf_renderer_stats st;
        wf_renderer_get_stats(r, &st);
        wf_renderer_destroy(r);
        ck_assert_msg(st.pieces_drawn == 0 && st.stamps_drawn == N && c.calls == N,
                      "tile height %d: %ld stamps whole, %ld pieces, %ld draws for %d objects", tiles[t],
                      st.stamps_drawn, st.pieces_drawn, c.calls, N);
        ck_assert_uint_le(st.pool_high_water, cfg.pool_bytes);
        ck_assert_msg(!memcmp(ref, img, sizeof(float) * W * H), "tile height %d changes the rates", tiles[t]);
        free(img);
    }
    free(ref);
}
END_TEST

/* The layer (wf_renderer_config.layer): every row the source fills, summed over the flagged
 * objects alone, is the rates of a renderer of those objects alone without sky, bit for bit,
 * halo objects included, whatever the tiles (halo rows come twice, the same); and asking for
 * it changes none of the rates. */
typedef struct layer_img {
    int ncols;
    float *img;
    unsigned char *seen;
    int mismatch;
} layer_img;

static void layer_row(void *ctx, int y, const float *rates, int ncols)
{
    layer_img *l = ctx;
    float *row = l->img + (size_t)y * ncols;
    if (l->seen[y] && memcmp(row, rates, (size_t)ncols * sizeof *row)) l->mismatch = 1;
    memcpy(row, rates, (size_t)ncols * sizeof *row);
    l->seen[y] = 1;
}

START_TEST(layer_is_the_flagged_objects_alone)
{
    enum { N = 300, W = 120, H = 150 };
    static gauss g[N];
    static wf_render_object o[N], ob[N];
    make_objects(N, W, H, g, o, 11);
    int nb = 0;
    for (int i = 0; i < N; i++) {
        if (i % 5 == 0) { /* a halo object: its box and a wider Gaussian over the footprint */
            g[i].halo_sigma = 1.5 * g[i].sigma;
            g[i].halo_flux = 0.2 * g[i].flux;
            o[i].halo = 1;
        }
        o[i].layer = i % 3 == 0;
        if (o[i].layer) ob[nb++] = o[i];
    }
    static float limg[W * H];
    static unsigned char seen[H];
    counter c = {0, 0};
    wf_renderer_config plain = {W, H, 0.4, NULL, NULL, 1u << 22, 0, halo_gauss, NULL, NULL, NULL, NULL, NULL, 0.0};
    float *want_all = render_all(&plain, o, N, H, &c);
    wf_renderer_config alone = {W, H, 0.0, NULL, NULL, 1u << 22, 0, halo_gauss, NULL, NULL, NULL, NULL, NULL, 0.0};
    float *want_layer = render_all(&alone, ob, nb, H, &c);
    const int tiles[] = {1, 7, H};
    for (int t = 0; t < 3; t++) {
        layer_img l = {W, limg, seen, 0};
        memset(limg, 0, sizeof limg);
        memset(seen, 0, sizeof seen);
        wf_renderer_config cfg = {W, H, 0.4, NULL, NULL, 1u << 22, 0, halo_gauss, layer_row, &l, NULL, NULL, NULL, 0.0};
        float *img = render_all(&cfg, o, N, tiles[t], &c);
        ck_assert_msg(!memcmp(img, want_all, sizeof limg), "tile %d: the layer changed the rates", tiles[t]);
        for (int y = 0; y < H; y++) ck_assert_msg(seen[y], "tile %d: row %d never came", tiles[t], y);
        ck_assert_msg(!l.mismatch, "tile %d: a row came twice, differently", tiles[t]);
        ck_assert_msg(!memcmp(limg, want_layer, sizeof limg), "tile %d: the layer is not the flagged objects alone",
                      tiles[t]);
        free(img);
    }
    double sum = 0.0;
    for (int k = 0; k < W * H; k++) sum += want_layer[k];
    ck_assert_msg(sum > 0.0 && nb > 50, "an empty layer proves nothing (%d objects, %g)", nb, sum);
    /* a floor: the layer's rates below it come as 0, the others as they were; the rates unmoved */
    {
        layer_img l = {W, limg, seen, 0};
        wf_renderer_config cfg = {W, H, 0.4, NULL, NULL, 1u << 22, 0, halo_gauss, layer_row, &l, NULL, NULL, NULL, 5.0};
        float *img = render_all(&cfg, o, N, 7, &c);
        ck_assert(!memcmp(img, want_all, sizeof limg));
        int below = 0, above = 0;
        for (int k = 0; k < W * H; k++) {
            ck_assert(limg[k] == (want_layer[k] >= 5.0f ? want_layer[k] : 0.0f));
            below += want_layer[k] > 0.0f && want_layer[k] < 5.0f;
            above += want_layer[k] >= 5.0f;
        }
        ck_assert_msg(below > 100 && above > 10, "the floor leaves %d pixels out and %d in", below, above);
        free(img);
    }
    free(want_all);
    free(want_layer);
}
END_TEST

/* The plane (wf_renderer_config.plane_put, plane_get): what one renderer hands over, a later
 * renderer of the same static objects with another sky and other variable objects takes
 * instead of drawing them (it draws only the variable ones), and its rates and layer are
 * those of a renderer that drew everything, bit for bit, whatever the tiles. */
typedef struct plane_img {
    int ncols, nrows;
    float *plane, *layer;
    unsigned char *seen;
    int mismatch, layers;
} plane_img;

static void plane_put(void *ctx, int y, const float *plane, const float *layer, int ncols)
{
    plane_img *p = ctx;
    float *row = p->plane + (size_t)y * ncols, *lrow = p->layer + (size_t)y * ncols;
    if (p->seen[y] && memcmp(row, plane, (size_t)ncols * sizeof *row)) p->mismatch = 1;
    memcpy(row, plane, (size_t)ncols * sizeof *row);
    if (layer) memcpy(lrow, layer, (size_t)ncols * sizeof *lrow), p->layers++;
    p->seen[y] = 1;
}

static wf_status plane_get(void *ctx, int y0, int y1, int ncols, float *plane, float *layer)
{
    plane_img *p = ctx;
    ck_assert(ncols == p->ncols && y0 >= 0 && y1 <= p->nrows);
    memcpy(plane, p->plane + (size_t)y0 * ncols, (size_t)(y1 - y0) * ncols * sizeof *plane);
    if (layer) memcpy(layer, p->layer + (size_t)y0 * ncols, (size_t)(y1 - y0) * ncols * sizeof *layer);
    return WF_OK;
}

START_TEST(plane_handed_over)
{
    enum { N = 300, W = 120, H = 150 };
    static gauss g[N], g2[N];
    static wf_render_object o[N], o2[N];
    make_objects(N, W, H, g, o, 13);
    for (int i = 0; i < N; i++) {
        if (i % 5 == 0) {
            g[i].halo_sigma = 1.5 * g[i].sigma;
            g[i].halo_flux = 0.2 * g[i].flux;
            o[i].halo = 1;
        }
        o[i].variable = i % 7 == 0;
        /* and some vary within the exposure, which makes them variable */
        if (i % 11 == 0) o[i].rel_slope = 1e-4, o[i].layer = 0;
        o[i].layer = !o[i].variable && o[i].rel_slope == 0.0 && i % 3 == 0;
    }
    /* the layer's objects alone, without sky, floored as the later renderers are */
    static wf_render_object ob[N];
    int nb = 0;
    for (int i = 0; i < N; i++)
        if (o[i].layer) ob[nb++] = o[i];
    const double floor = 2.0;
    /* the next exposure: other variable objects (brighter), another sky */
    memcpy(g2, g, sizeof g);
    memcpy(o2, o, sizeof o);
    for (int i = 0; i < N; i++) {
        o2[i].data = &g2[i];
        if (o[i].variable || o[i].rel_slope != 0.0) g2[i].flux *= 3.0;
    }
    static float pl[W * H], ly[W * H], limg[W * H], want_layer[W * H];
    static unsigned char seen[H], lseen[H];
    plane_img p = {W, H, pl, ly, seen, 0, 0};
    counter c = {0, 0};
    layer_img l0 = {W, limg, lseen, 0};
    wf_renderer_config first = {W, H, 0.4, NULL, NULL, 1u << 22, 0, halo_gauss, layer_row, &l0, NULL, plane_put, &p, floor};
    float *a = render_all(&first, o, N, 7, &c);
    wf_renderer_config plain = {W, H, 0.4, NULL, NULL, 1u << 22, 0, halo_gauss, NULL, NULL, NULL, NULL, NULL, 0.0};
    float *a_plain = render_all(&plain, o, N, H, &c);
    ck_assert_msg(!memcmp(a, a_plain, sizeof pl), "handing the plane over changed the rates");
    for (int y = 0; y < H; y++) ck_assert_msg(seen[y], "plane row %d never came", y);
    ck_assert_msg(!p.mismatch && p.layers > 0, "a plane row came twice, differently (or no layer came)");
    wf_renderer_config alone = {W, H, 0.0, NULL, NULL, 1u << 22, 0, halo_gauss, NULL, NULL, NULL, NULL, NULL, 0.0};
    float *lay = render_all(&alone, ob, nb, H, &c);
    int floored = 0;
    for (int k = 0; k < W * H; k++) {
        want_layer[k] = lay[k] >= floor ? lay[k] : 0.0f;
        floored += lay[k] > 0.0f && lay[k] < floor;
    }
    free(lay);
    ck_assert_msg(floored > 100 && nb > 50, "%d pixels under the floor, %d layer objects: nothing tested", floored, nb);
    ck_assert_msg(!memcmp(ly, want_layer, sizeof ly), "the layer handed over is not the floored layer objects alone");
    ck_assert_msg(!memcmp(limg, want_layer, sizeof ly), "the layer's user did not get the floored layer");
    plain.sky = 0.9;
    float *want = render_all(&plain, o2, N, H, &c);
    const int tiles[] = {1, 7, H};
    for (int t = 0; t < 3; t++) {
        layer_img l = {W, limg, lseen, 0};
        memset(limg, 0, sizeof limg);
        memset(lseen, 0, sizeof lseen);
        wf_renderer_config later = {W, H, 0.9, NULL, NULL, 1u << 22, 0, halo_gauss, layer_row, &l, plane_get, NULL, &p, floor};
        counter c2 = {0, 0};
        float *b = render_all(&later, o2, N, tiles[t], &c2);
        ck_assert_msg(!memcmp(b, want, sizeof pl), "tile %d: the plane given back changes the rates", tiles[t]);
        ck_assert_msg(!memcmp(limg, want_layer, sizeof limg), "tile %d: the layer given back differs", tiles[t]);
        long drawn_variable = 0;
        for (int i = 0; i < N; i++) drawn_variable += o[i].variable || o[i].rel_slope != 0.0;
        ck_assert(drawn_variable > (N + 6) / 7); /* rel_slope alone made some variable */
        if (tiles[t] == H) /* one request: each stamp drawn once */
            ck_assert_msg(c2.calls <= drawn_variable && c2.calls > 0,
                          "%ld draws for %ld variable objects: static ones were drawn", c2.calls, drawn_variable);
        free(b);
    }
    free(a);
    free(a_plain);
    free(want);
}
END_TEST

static Suite *suite(void)
{
    Suite *s = suite_create("render");
    TCase *tc = tcase_create("render");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, tile_height_and_pool_do_not_matter);
    tcase_add_test(tc, layer_is_the_flagged_objects_alone);
    tcase_add_test(tc, plane_handed_over);
    tcase_add_test(tc, flux_conserved_and_off_sca_skipped);
    tcase_add_test(tc, crowded_tile_and_empty_scene);
    tcase_add_test(tc, each_stamp_drawn_once);
    tcase_add_test(tc, pool_kept_near_live_stamps);
    tcase_add_test(tc, passed_rows_leave_the_pool);
    tcase_add_test(tc, halo_objects);
    tcase_add_test(tc, halo_clipped);
    tcase_add_test(tc, negatives_clipped_in_the_sum);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(suite()); }
