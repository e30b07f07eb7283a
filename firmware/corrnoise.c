#include "firmware/corrnoise.h"

#include <math.h>
#include <string.h>

/* Keys of the draws (purpose 8: tree and offsets, 9: steps and reference read noise):
 *   bridge node m of realisation `key`   (pixel m, read key, purpose 8), word c x 12 + j
 *   offset of channel c                   (pixel OFFSET_PIXEL + c, read 0, purpose 8), word 0
 *   step into position i of channel c     (pixel Y x 4096 + c x 128 + i, read key, purpose 9),
 *                                          words 0..11, one per component
 *   step of the shared process            (pixel SHARED_PIXEL + Y x 128 + i, ...), the same
 *   white read noise of reference pixel X (pixel Y x 4096 + X, read key, purpose 9), block 3 */
#define OFFSET_PIXEL 0x40000000u
#define SHARED_PIXEL 0x01000000u /* 4096 x 4096: above every row's channel pixels */

void wf_corrnoise_components(double lambda[WF_CN_NCOMP], double *sd)
{
    /* corners from one per frame to the Nyquist frequency of the pixel clock, per pixel time */
    const double lo = 1.0 / ((double)WF_CN_FRAME_ROWS * WF_CN_ROW_TIME), hi = 0.5;
    for (int j = 0; j < WF_CN_NCOMP; j++)
        lambda[j] = 2.0 * M_PI * lo * pow(hi / lo, (double)j / (WF_CN_NCOMP - 1));
    /* equal variances on log-spaced corners sum to a 1/f spectrum between them */
    *sd = sqrt(1.0 / WF_CN_NCOMP);
}

double wf_corrnoise_acov(double k)
{
    double lambda[WF_CN_NCOMP], sd, s = 0.0;
    wf_corrnoise_components(lambda, &sd);
    for (int j = 0; j < WF_CN_NCOMP; j++) s += exp(-lambda[j] * fabs(k));
    return sd * sd * s;
}

/* An OU value d1 pixel times after x_a and d2 before x_b: mean a x_a + b x_b, rms c x sd
 * (the bridge; the 1 - r^2 terms by expm1, as rates times short steps are small). */
static void bridge_coef(double lam, double d1, double d2, double *a, double *b, double *c)
{
    double r1 = exp(-lam * d1), r2 = exp(-lam * d2);
    double q1 = -expm1(-2.0 * lam * d1), q2 = -expm1(-2.0 * lam * d2);
    double den = -expm1(-2.0 * lam * (d1 + d2));
    *a = r1 * q2 / den;
    *b = r2 * q1 / den;
    *c = sqrt(q1 * q2 / den);
}

static int words_of(const wf_corrnoise *cn) { return (cn->nchan + 1) * WF_CN_CHANNEL_COLS; }

size_t wf_corrnoise_arena_need(int ncols)
{
    int nchan = (ncols + 2 * WF_CN_BORDER + WF_CN_CHANNEL_COLS - 1) / WF_CN_CHANNEL_COLS;
    size_t nw = (size_t)(nchan + 1) * WF_CN_CHANNEL_COLS;
    return wf_arena_cost((size_t)nchan * sizeof(double)) +
           2 * wf_arena_cost((size_t)(nchan + 1) * WF_CN_NCOMP * sizeof(double)) +
           wf_arena_cost(4 * nw * sizeof(uint32_t)) + wf_arena_cost(WF_CN_NCOMP * nw * sizeof(float)) +
           wf_arena_cost(nw * sizeof(double));
}

wf_status wf_corrnoise_init(wf_corrnoise *cn, const wf_detector *det, const wf_noise *noise, int ncols,
                            int nrows, wf_arena *arena)
{
    memset(cn, 0, sizeof *cn);
    cn->noise = *noise;
    cn->width = ncols + 2 * WF_CN_BORDER;
    cn->height = nrows + 2 * WF_CN_BORDER;
    cn->nchan = (cn->width + WF_CN_CHANNEL_COLS - 1) / WF_CN_CHANNEL_COLS;
    /* the row buffers hold a full frame's channels, and the noise keys (Y x 4096 + X) a
     * full frame's columns */
    if (cn->width > WF_CN_FRAME_ROWS)
        return wf_error(WF_ERR_RANGE, "correlated noise: %d columns with the border exceed a frame's %d",
                        cn->width, WF_CN_FRAME_ROWS);
    while ((1 << cn->levels) < cn->height) cn->levels++;
    if (cn->levels > WF_CN_MAX_LEVELS)
        return wf_error(WF_ERR_RANGE, "correlated noise: %d rows exceed the bridge's %d", cn->height,
                        1 << WF_CN_MAX_LEVELS);
    if (det->on.read_1f) {
        cn->amp_c = det->rn1f_corr_e;
        cn->amp_u = det->rn1f_uncorr_e;
    }
    wf_corrnoise_components(cn->lambda, &cn->sd);
    /* the bridge's coefficients depend on the level only: intervals of a level are alike */
    const double P = WF_CN_ROW_TIME, N = (double)(1 << cn->levels);
    for (int j = 0; j < WF_CN_NCOMP; j++) {
        cn->frame_end[j][0] = exp(-cn->lambda[j] * P * N);
        cn->frame_end[j][1] = sqrt(-expm1(-2.0 * cn->lambda[j] * P * N));
        for (int l = 0; l < cn->levels; l++) {
            double h = P * (double)(1 << (cn->levels - l - 1));
            bridge_coef(cn->lambda[j], h, h, &cn->mid[l][j][0], &cn->mid[l][j][1], &cn->mid[l][j][2]);
        }
    }
    for (int j = 0; j < WF_CN_NCOMP; j++) {
        cn->step[j][0][0] = 1.0; /* position 0 is the row's start itself */
        for (int i = 1; i < WF_CN_CHANNEL_COLS; i++)
            bridge_coef(cn->lambda[j], 1.0, WF_CN_ROW_TIME - i, &cn->step[j][i][0], &cn->step[j][i][1],
                        &cn->step[j][i][2]);
    }
    void *p;
    wf_status st;
    size_t nstate = (size_t)(cn->nchan + 1) * WF_CN_NCOMP, nw = (size_t)words_of(cn);
    if ((st = wf_arena_calloc(arena, (size_t)cn->nchan, sizeof(double), "channel offsets", &p))) return st;
    cn->offset = p;
    if ((st = wf_arena_calloc(arena, nstate, sizeof(double), "1/f row starts", &p))) return st;
    cn->x0 = p;
    if ((st = wf_arena_calloc(arena, nstate, sizeof(double), "1/f next row starts", &p))) return st;
    cn->x1 = p;
    if ((st = wf_arena_calloc(arena, 4 * nw, sizeof(uint32_t), "1/f noise words", &p))) return st;
    cn->w = p;
    if ((st = wf_arena_calloc(arena, WF_CN_NCOMP * nw, sizeof(float), "1/f normals", &p))) return st;
    cn->z = p;
    if ((st = wf_arena_calloc(arena, nw, sizeof(double), "1/f paths", &p))) return st;
    cn->path = p;
    if (det->on.channel_offsets && noise->kind != WF_NOISE_OFF)
        for (int c = 0; c < cn->nchan; c++) {
            wf_rng rng;
            wf_rng_init(&rng, noise, OFFSET_PIXEL + (uint32_t)c, 0, WF_PURPOSE_1F_TREE);
            cn->offset[c] = det->channel_offset_adu * det->gain * wf_rng_gauss(&rng);
        }
    return WF_OK;
}

/* Standard normals of bridge node m: z[c x 12 + j] for the nchan + 1 processes. */
static void node_normals(wf_corrnoise *cn, uint32_t key, uint32_t m, double *z)
{
    int n = (cn->nchan + 1) * WF_CN_NCOMP, nb = (n + 3) / 4;
    uint32_t *w = cn->w; /* idle between rows: the step words are drawn after the nodes */
    wf_noise_stream_blocks(&cn->noise, m, key, WF_PURPOSE_1F_TREE, 0, nb, w, w + nb, w + 2 * nb, w + 3 * nb);
    float *zf = cn->z; /* idle too */
    wf_norm_from_u32(w, 4 * nb, zf);
    for (int i = 0; i < n; i++) z[i] = zf[(i % 4) * nb + i / 4];
}

/* The processes' values at the start of row Y (xs[c x 12 + j], unit amplitude): down the
 * dyadic tree from the frame's two ends, each node drawn given the ends of its interval. */
static void row_start(wf_corrnoise *cn, uint32_t key, int Y, double *xs)
{
    enum { MAXN = (WF_CN_FRAME_ROWS / WF_CN_CHANNEL_COLS + 2) * WF_CN_NCOMP };
    double xa[MAXN], xb[MAXN], z[MAXN];
    const int n = (cn->nchan + 1) * WF_CN_NCOMP;
    const int N = 1 << cn->levels;
    node_normals(cn, key, 0, z);
    for (int i = 0; i < n; i++) xa[i] = cn->sd * z[i];
    if (Y == 0) { memcpy(xs, xa, (size_t)n * sizeof *xs); return; }
    node_normals(cn, key, (uint32_t)N, z);
    for (int j = 0; j < WF_CN_NCOMP; j++) {
        double r = cn->frame_end[j][0], q = cn->frame_end[j][1];
        for (int c = 0; c <= cn->nchan; c++) {
            int i = c * WF_CN_NCOMP + j;
            xb[i] = r * xa[i] + q * cn->sd * z[i];
        }
    }
    if (Y == N) { memcpy(xs, xb, (size_t)n * sizeof *xs); return; }
    int a = 0, b = N;
    for (int level = 0;; level++) {
        int m = (a + b) / 2;
        double *xm = Y < m ? xb : xa; /* the end replaced by the midpoint */
        node_normals(cn, key, (uint32_t)m, z);
        for (int j = 0; j < WF_CN_NCOMP; j++) {
            const double ca = cn->mid[level][j][0], cb = cn->mid[level][j][1], cc = cn->mid[level][j][2];
            for (int c = 0; c <= cn->nchan; c++) {
                int i = c * WF_CN_NCOMP + j;
                xm[i] = ca * xa[i] + cb * xb[i] + cc * cn->sd * z[i];
            }
        }
        if (Y == m) { memcpy(xs, xm, (size_t)n * sizeof *xs); return; }
        if (Y < m) b = m; else a = m;
    }
}

/* Normals of the row's steps: z[j][c x 128 + i], the shared process at c = nchan. */
static void step_normals(wf_corrnoise *cn, uint32_t key, int Y)
{
    const int nw = words_of(cn), nu = cn->nchan * WF_CN_CHANNEL_COLS;
    uint32_t *w = cn->w;
    for (int b = 0; b < WF_CN_NCOMP / 4; b++) {
        if (cn->amp_u > 0.0)
            wf_noise_block_row(&cn->noise, (uint32_t)Y * 4096u, nu, key, WF_PURPOSE_1F_STEP, (uint32_t)b, w,
                               w + nw, w + 2 * nw, w + 3 * nw);
        if (cn->amp_c > 0.0)
            wf_noise_block_row(&cn->noise, SHARED_PIXEL + (uint32_t)Y * WF_CN_CHANNEL_COLS, WF_CN_CHANNEL_COLS,
                               key, WF_PURPOSE_1F_STEP, (uint32_t)b, w + nu, w + nw + nu, w + 2 * nw + nu,
                               w + 3 * nw + nu);
        for (int k = 0; k < 4; k++) wf_norm_from_u32(w + (size_t)k * nw, nw, cn->z + (size_t)(4 * b + k) * nw);
    }
}

/* path[c][i] = amplitude x process c's value at readout position i, for the processes
 * c0 .. c1 - 1: all channels advance together, so the sequential recursion of one channel
 * overlaps the others' (independent chains) rather than waiting on its own latency. */
static void paths(wf_corrnoise *cn, int c0, int c1, const double *amp)
{
    const int nw = words_of(cn);
    double (*path)[WF_CN_CHANNEL_COLS] = (double (*)[WF_CN_CHANNEL_COLS])cn->path;
    double x[WF_CN_FRAME_ROWS / WF_CN_CHANNEL_COLS + 2], end[WF_CN_FRAME_ROWS / WF_CN_CHANNEL_COLS + 2];
    memset(path + c0, 0, (size_t)(c1 - c0) * sizeof *path);
    for (int j = 0; j < WF_CN_NCOMP; j++) {
        const float *z = cn->z + (size_t)j * nw;
        for (int c = c0; c < c1; c++) {
            x[c] = cn->x0[c * WF_CN_NCOMP + j];
            end[c] = cn->x1[c * WF_CN_NCOMP + j];
            path[c][0] += amp[c] * x[c];
        }
        for (int i = 1; i < WF_CN_CHANNEL_COLS; i++) {
            const double a = cn->step[j][i][0], b = cn->step[j][i][1], sd = cn->step[j][i][2] * cn->sd;
            for (int c = c0; c < c1; c++) {
                x[c] = a * x[c] + b * end[c] + sd * (double)z[c * WF_CN_CHANNEL_COLS + i];
                path[c][i] += amp[c] * x[c];
            }
        }
    }
}

void wf_corrnoise_row(wf_corrnoise *cn, uint32_t key, int Y, double scale, double *out)
{
    const int W = cn->width;
    for (int X = 0; X < W; X++) out[X] = cn->offset[X / WF_CN_CHANNEL_COLS];
    if (!(cn->amp_c > 0.0 || cn->amp_u > 0.0) || scale == 0.0) return;
    const size_t ns = (size_t)(cn->nchan + 1) * WF_CN_NCOMP;
    if (cn->have_row && cn->next_row == Y && cn->next_key == key) /* rows in order: the start known */
        memcpy(cn->x0, cn->x1, ns * sizeof *cn->x0);
    else
        row_start(cn, key, Y, cn->x0);
    row_start(cn, key, Y + 1, cn->x1);
    cn->have_row = 1;
    cn->next_row = Y + 1;
    cn->next_key = key;
    step_normals(cn, key, Y);
    double amp[WF_CN_FRAME_ROWS / WF_CN_CHANNEL_COLS + 2];
    for (int c = 0; c < cn->nchan; c++) amp[c] = cn->amp_u * scale;
    amp[cn->nchan] = cn->amp_c * scale;
    /* the processes with an amplitude: the channels' own, the shared one, or both */
    paths(cn, cn->amp_u > 0.0 ? 0 : cn->nchan, cn->amp_c > 0.0 ? cn->nchan + 1 : cn->nchan, amp);
    const double (*path)[WF_CN_CHANNEL_COLS] = (const double (*)[WF_CN_CHANNEL_COLS])cn->path;
    for (int c = 0; c < cn->nchan; c++) {
        int X0 = c * WF_CN_CHANNEL_COLS, X1 = X0 + WF_CN_CHANNEL_COLS < W ? X0 + WF_CN_CHANNEL_COLS : W;
        for (int X = X0; X < X1; X++) {
            int i = wf_corrnoise_position(X);
            out[X] += (cn->amp_u > 0.0 ? path[c][i] : 0.0) + (cn->amp_c > 0.0 ? path[cn->nchan][i] : 0.0);
        }
    }
}

void wf_corrnoise_ref_normals(wf_corrnoise *cn, uint32_t key, int Y, int X0, int n, float *z)
{
    uint32_t *w = cn->w;
    wf_noise_block_row(&cn->noise, (uint32_t)Y * 4096u + (uint32_t)X0, n, key, WF_PURPOSE_1F_STEP, 3, w, w + n,
                       w + 2 * n, w + 3 * n);
    wf_norm_from_u32(w, n, z);
}
