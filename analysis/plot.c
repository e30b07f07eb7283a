#include "analysis/plot.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "analysis/png.h"

/* ---- font: 5x7 cells, one byte per row, bit 4 = leftmost column; ASCII 32..126. g p q y are
 * drawn two rows lower (descenders), in a 9-row line. ------------------------------------------ */

static const unsigned char font[95][7] = {
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00}, {0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04},
    {0x0A, 0x0A, 0x00, 0x00, 0x00, 0x00, 0x00}, {0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A},
    {0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04}, {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03},
    {0x08, 0x14, 0x14, 0x08, 0x15, 0x12, 0x0D}, {0x04, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00},
    {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}, {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08},
    {0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00}, {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00},
    {0x00, 0x00, 0x00, 0x00, 0x04, 0x04, 0x08}, {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00},
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x04}, {0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10},
    {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}, {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}, /* 0 1 */
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}, {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E},
    {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}, {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E},
    {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}, {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08},
    {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}, {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C},
    {0x00, 0x00, 0x04, 0x00, 0x00, 0x04, 0x00}, {0x00, 0x00, 0x04, 0x00, 0x04, 0x04, 0x08},
    {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02}, {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00},
    {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08}, {0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04},
    {0x0E, 0x11, 0x17, 0x15, 0x17, 0x10, 0x0E}, {0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}, /* @ A */
    {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E}, {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E},
    {0x1E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1E}, {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F},
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10}, {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F},
    {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}, {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},
    {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C}, {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11},
    {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F}, {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11},
    {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11}, {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},
    {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10}, {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D},
    {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11}, {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E},
    {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}, {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}, {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A},
    {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11}, {0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04},
    {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F}, {0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E},
    {0x10, 0x10, 0x08, 0x04, 0x02, 0x01, 0x01}, {0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E},
    {0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00}, {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F},
    {0x08, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00}, {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F}, /* ` a */
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E}, {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E},
    {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F}, {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E},
    {0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08}, {0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E},
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11}, {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E},
    {0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C}, {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12},
    {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}, {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11},
    {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11}, {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E},
    {0x1E, 0x11, 0x11, 0x11, 0x1E, 0x10, 0x10}, {0x0F, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x01},
    {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10}, {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E},
    {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06}, {0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D},
    {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04}, {0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A},
    {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11}, {0x11, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E},
    {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F}, {0x02, 0x04, 0x04, 0x08, 0x04, 0x04, 0x02},
    {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}, {0x08, 0x04, 0x04, 0x02, 0x04, 0x04, 0x08},
    {0x00, 0x00, 0x08, 0x15, 0x02, 0x00, 0x00},
};
static const unsigned char glyph_degree[7] = {0x0C, 0x12, 0x12, 0x0C, 0x00, 0x00, 0x00};

#define FW 6 /* advance: 5 columns + 1 space */
#define FH 7

/* The glyph of the next character of *s (advancing it), NULL at the end. UTF-8 labels are
 * common ("RA (°)", "−"): those two get glyphs, any other non-ASCII character a '?'. */
static const unsigned char *next_glyph(const char **s)
{
    const unsigned char *u = (const unsigned char *)*s;
    if (!*u) return NULL;
    if (*u < 0x80) {
        (*s)++;
        return font[*u >= 32 && *u <= 126 ? *u - 32 : '?' - 32];
    }
    int n = 1;
    while (u[n] && (u[n] & 0xC0) == 0x80) n++;
    *s += n;
    if (n == 2 && u[0] == 0xC2 && u[1] == 0xB0) return glyph_degree;
    if (n == 3 && u[0] == 0xE2 && u[1] == 0x88 && u[2] == 0x92) return font['-' - 32];
    return font['?' - 32];
}

static int descends(const unsigned char *g)
{
    return g == font['g' - 32] || g == font['p' - 32] || g == font['q' - 32] || g == font['y' - 32];
}

static int text_width(const char *s, int scale)
{
    int n = 0;
    while (s && next_glyph(&s)) n++;
    return n ? (n * FW - 1) * scale : 0;
}

/* ---- canvas ------------------------------------------------------------------------------------ */

typedef unsigned char rgb_t[3];
static const rgb_t white = {255, 255, 255}, black = {0, 0, 0}, grid = {228, 228, 228};
static const rgb_t palette[] = {{0, 90, 200},  {230, 110, 0},  {0, 150, 70},  {200, 30, 40},
                                {130, 60, 170}, {120, 80, 40}, {0, 160, 170}, {210, 60, 150}};
#define NPALETTE (int)(sizeof palette / sizeof palette[0])

typedef struct {
    unsigned char *px;
    int w, h;
    int cl, ct, cr, cb; /* clip rectangle, inclusive */
} canvas;

static void noclip(canvas *c)
{
    c->cl = c->ct = 0;
    c->cr = c->w - 1;
    c->cb = c->h - 1;
}

static void pset(canvas *c, int x, int y, const unsigned char *col)
{
    if (x >= c->cl && x <= c->cr && y >= c->ct && y <= c->cb)
        memcpy(c->px + 3 * ((size_t)y * c->w + x), col, 3);
}

static void fill(canvas *c, int x0, int y0, int x1, int y1, const unsigned char *col)
{
    for (int y = y0 > c->ct ? y0 : c->ct; y <= y1 && y <= c->cb; y++)
        for (int x = x0 > c->cl ? x0 : c->cl; x <= x1 && x <= c->cr; x++) pset(c, x, y, col);
}

static void rect(canvas *c, int x0, int y0, int x1, int y1, const unsigned char *col)
{
    fill(c, x0, y0, x1, y0, col);
    fill(c, x0, y1, x1, y1, col);
    fill(c, x0, y0, x0, y1, col);
    fill(c, x1, y0, x1, y1, col);
}

/* Bresenham between integer end points. */
static void iline(canvas *c, int x0, int y0, int x1, int y1, const unsigned char *col)
{
    int dx = abs(x1 - x0), dy = -abs(y1 - y0), sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
    int err = dx + dy;
    for (;;) {
        pset(c, x0, y0, col);
        if (x0 == x1 && y0 == y1) return;
        int e2 = 2 * err;
        if (e2 >= dy) { err += dy; x0 += sx; }
        if (e2 <= dx) { err += dx; y0 += sy; }
    }
}

/* A segment in pixel coordinates, cut to the clip rectangle first (Liang-Barsky) so that far-off
 * points neither overflow an int nor cost a walk across millions of invisible pixels. */
static void line(canvas *c, double x0, double y0, double x1, double y1, const unsigned char *col)
{
    const double big = 1e7;
    x0 = fmax(-big, fmin(big, x0)), y0 = fmax(-big, fmin(big, y0));
    x1 = fmax(-big, fmin(big, x1)), y1 = fmax(-big, fmin(big, y1));
    double dx = x1 - x0, dy = y1 - y0, u0 = 0, u1 = 1;
    double p[4] = {-dx, dx, -dy, dy};
    double q[4] = {x0 - (c->cl - 0.5), c->cr + 0.5 - x0, y0 - (c->ct - 0.5), c->cb + 0.5 - y0};
    for (int i = 0; i < 4; i++) {
        if (p[i] == 0) {
            if (q[i] < 0) return;
            continue;
        }
        double u = q[i] / p[i];
        if (p[i] < 0) u0 = fmax(u0, u);
        else u1 = fmin(u1, u);
    }
    if (u0 > u1) return;
    iline(c, (int)lround(x0 + u0 * dx), (int)lround(y0 + u0 * dy), (int)lround(x0 + u1 * dx),
          (int)lround(y0 + u1 * dy), col);
}

/* Text with its top-left corner at (x, y); vertical text is turned a quarter counter-clockwise
 * (read bottom to top) with (x, y) its bottom-left corner. */
static void text(canvas *c, int x, int y, const char *s, int scale, int vertical,
                 const unsigned char *col)
{
    const unsigned char *g;
    for (int u0 = 0; s && (g = next_glyph(&s)) != NULL; u0 += FW * scale)
        for (int r = 0, drop = descends(g) ? 2 * scale : 0; r < FH * scale; r++)
            for (int k = 0; k < 5 * scale; k++)
                if (g[r / scale] & (0x10 >> (k / scale))) {
                    int u = u0 + k, v = r + drop;
                    if (vertical) pset(c, x + v, y - u, col);
                    else pset(c, x + u, y + v, col);
                }
}

void wf_plot_colormap(double t, unsigned char rgb[3])
{
    /* Nine anchors of a viridis-like map, each lighter than the last. */
    static const unsigned char cm[9][3] = {{68, 1, 84},    {71, 44, 122},  {59, 81, 139},
                                           {44, 113, 142}, {33, 144, 141}, {39, 173, 129},
                                           {92, 200, 99},  {170, 220, 50}, {253, 231, 37}};
    t = isnan(t) ? 0 : t < 0 ? 0 : t > 1 ? 1 : t;
    double f = t * 8;
    int i = f >= 8 ? 7 : (int)f;
    f -= i;
    for (int k = 0; k < 3; k++) rgb[k] = (unsigned char)lround(cm[i][k] + f * (cm[i + 1][k] - cm[i][k]));
}

/* ---- ticks ------------------------------------------------------------------------------------- */

int wf_plot_nice_ticks(double lo, double hi, int target, double *ticks, int max)
{
    if (!isfinite(lo) || !isfinite(hi) || lo >= hi || !isfinite(hi - lo) || max < 1) return 0;
    int want = target > 4 ? target : 4;
    if (want > max) want = max;
    static const double mant[3] = {5, 2, 1};
    double dec = pow(10, floor(log10(hi - lo))) * 10; /* step 1e(k+1) leaves at most 1 tick */
    for (int i = 0; i < 60; i++) {
        double step = mant[i % 3] * dec * pow(10, -(i / 3));
        if (step <= 0) return 0;
        double m0 = ceil(lo / step), m1 = floor(hi / step);
        if (m1 - m0 + 1 < want) continue;
        int n = 0;
        for (int j = 0; j <= (int)(m1 - m0) && n < max; j++) {
            double t = (m0 + j) * step;
            if (t >= lo - 1e-9 * step && t <= hi + 1e-9 * step) ticks[n++] = t;
        }
        return n;
    }
    return 0;
}

/* Ticks of a log axis over [10^lo, 10^hi] (lo, hi in decades), in user units. */
static int log_ticks(double lo, double hi, double *t, int max)
{
    int k0 = (int)ceil(lo - 1e-9), k1 = (int)floor(hi + 1e-9), n = 0;
    if (k1 - k0 + 1 >= 3) {
        int every = (k1 - k0 + 8) / 8;
        for (int k = k0; k <= k1 && n < max; k++)
            if (((k % every) + every) % every == 0) t[n++] = pow(10, k);
        return n;
    }
    static const double mant[3] = {1, 2, 5};
    for (int k = (int)floor(lo); k <= (int)ceil(hi) && n < max; k++)
        for (int i = 0; i < 3 && n < max; i++) {
            double v = mant[i] * pow(10, k), lv = log10(v);
            if (lv >= lo - 1e-9 && lv <= hi + 1e-9) t[n++] = v;
        }
    return n >= 3 ? n : wf_plot_nice_ticks(pow(10, lo), pow(10, hi), 4, t, max);
}

/* ---- plots ------------------------------------------------------------------------------------- */

#define MAXTICKS 40

typedef struct {
    double *x, *y, *e;
    int n, style;
    char *label;
} series;

struct wf_plot {
    int w, h;
    char *title, *xlabel, *ylabel;
    int fixed, log[2], inverty;
    double range[4]; /* set_range: xmin xmax ymin ymax */
    series *s;
    int ns;
    /* from finish(): axis ends (log10 on log axes), ticks (user units), frame */
    double lo[2], hi[2], tick[2][MAXTICKS];
    int ntick[2], L, R, T, B;
};

static char *dupstr(const char *s)
{
    char *d = s ? malloc(strlen(s) + 1) : NULL;
    return d ? strcpy(d, s) : NULL;
}

wf_status wf_plot_create(int width, int height, const char *title, const char *xlabel,
                         const char *ylabel, wf_plot **out)
{
    *out = NULL;
    if (width < 64 || height < 64 || width > 8000 || height > 8000)
        return wf_error(WF_ERR_RANGE, "plot size %dx%d outside 64..8000 pixels", width, height);
    wf_plot *p = calloc(1, sizeof *p);
    if (!p) return wf_error(WF_ERR_NOMEM, "no memory for a plot");
    p->w = width;
    p->h = height;
    p->title = dupstr(title);
    p->xlabel = dupstr(xlabel);
    p->ylabel = dupstr(ylabel);
    if ((title && !p->title) || (xlabel && !p->xlabel) || (ylabel && !p->ylabel)) {
        wf_plot_free(p);
        return wf_error(WF_ERR_NOMEM, "no memory for a plot");
    }
    *out = p;
    return WF_OK;
}

wf_status wf_plot_set_range(wf_plot *p, double xmin, double xmax, double ymin, double ymax)
{
    if (!(isfinite(xmin) && isfinite(xmax) && isfinite(ymin) && isfinite(ymax) && xmin < xmax &&
          ymin < ymax))
        return wf_error(WF_ERR_RANGE, "plot range x %g..%g, y %g..%g: need finite min < max",
                        xmin, xmax, ymin, ymax);
    p->fixed = 1;
    p->range[0] = xmin, p->range[1] = xmax, p->range[2] = ymin, p->range[3] = ymax;
    return WF_OK;
}

wf_status wf_plot_set_log(wf_plot *p, int logx, int logy)
{
    p->log[0] = !!logx;
    p->log[1] = !!logy;
    return WF_OK;
}

wf_status wf_plot_invert_y(wf_plot *p, int on)
{
    p->inverty = !!on;
    return WF_OK;
}

wf_status wf_plot_series(wf_plot *p, const double *x, const double *y, const double *yerr, int n,
                         const char *label, int style)
{
    if (n < 0 || (n > 0 && (!x || !y)))
        return wf_error(WF_ERR_INPUT, "plot series '%s': %d points without data", label ? label : "",
                        n);
    if (style < 1 || style > 7 || ((style & WF_PLOT_ERRORBARS) && !yerr && n > 0))
        return wf_error(WF_ERR_INPUT, "plot series '%s': style %d (%s)", label ? label : "", style,
                        style & WF_PLOT_ERRORBARS ? "error bars need yerr" : "not a WF_PLOT_* mix");
    series *grown = realloc(p->s, (size_t)(p->ns + 1) * sizeof *grown);
    if (!grown) return wf_error(WF_ERR_NOMEM, "no memory for a plot series");
    p->s = grown;
    series *s = &p->s[p->ns];
    size_t bytes = (size_t)(n ? n : 1) * sizeof(double);
    *s = (series){malloc(bytes), malloc(bytes), yerr ? malloc(bytes) : NULL, n, style, dupstr(label)};
    if (!s->x || !s->y || (yerr && !s->e) || (label && !s->label)) {
        free(s->x), free(s->y), free(s->e), free(s->label);
        return wf_error(WF_ERR_NOMEM, "no memory for a plot series of %d points", n);
    }
    if (n) {
        memcpy(s->x, x, (size_t)n * sizeof(double));
        memcpy(s->y, y, (size_t)n * sizeof(double));
        if (yerr) memcpy(s->e, yerr, (size_t)n * sizeof(double));
    }
    p->ns++;
    return WF_OK;
}

static int usable(double v, int lg) { return isfinite(v) && (!lg || v > 0); }
static double axis_t(const wf_plot *p, int a, double v) { return p->log[a] ? log10(v) : v; }

static void extend(double *lo, double *hi, double v)
{
    if (v < *lo) *lo = v;
    if (v > *hi) *hi = v;
}

/* %g with digits enough to tell neighbouring ticks apart (MJD 61000.5 is not 61000). */
static int label_prec(const double *t, int n)
{
    double big = n ? fmax(fabs(t[0]), fabs(t[n - 1])) : 0, step = n > 1 ? fabs(t[1] - t[0]) : 0;
    int prec = big > 0 && step > 0 ? (int)floor(log10(big)) - (int)floor(log10(step)) + 1 : 0;
    return prec < 6 ? 6 : prec > 17 ? 17 : prec;
}

static int tick_label(char *buf, size_t n, double v, int prec)
{
    snprintf(buf, n, "%.*g", prec, fabs(v) < 1e-300 ? 0.0 : v); /* m * step can be -0 */
    return text_width(buf, 1);
}

static int labels_width(const double *t, int n)
{
    char buf[64];
    int w = 0, prec = label_prec(t, n);
    for (int i = 0; i < n; i++) {
        int lw = tick_label(buf, sizeof buf, t[i], prec);
        if (lw > w) w = lw;
    }
    return w;
}

/* Tick marks (4 px outward from the frame line next to `at`) and labels of one axis at pixel
 * positions q: side 0 below a frame, 1 left of it, 2 right of it. Labels that would touch are
 * thinned to every k-th. */
static void axis_ticks(canvas *c, const double *t, const int *q, int n, int side, int at)
{
    char buf[64];
    int prec = label_prec(t, n), need = side ? FH + 4 : labels_width(t, n) + 8, gap = 1 << 30;
    for (int i = 1; i < n; i++)
        if (abs(q[i] - q[i - 1]) < gap) gap = abs(q[i] - q[i - 1]);
    int every = gap >= need ? 1 : gap > 0 ? (need + gap - 1) / gap : n;
    for (int i = 0; i < n; i++) {
        int lw = tick_label(buf, sizeof buf, t[i], prec), show = i % every == 0;
        if (side == 0) {
            fill(c, q[i], at, q[i], at + 3, black);
            if (show) text(c, q[i] - lw / 2, at + 7, buf, 1, 0, black);
        } else if (side == 1) {
            fill(c, at - 3, q[i], at, q[i], black);
            if (show) text(c, at - 6 - lw, q[i] - FH / 2, buf, 1, 0, black);
        } else {
            fill(c, at, q[i], at + 3, q[i], black);
            if (show) text(c, at + 7, q[i] - FH / 2, buf, 1, 0, black);
        }
    }
}

/* Final ranges, ticks and frame for the current series. */
static wf_status finish(wf_plot *p)
{
    for (int a = 0; a < 2; a++) {
        double lo = INFINITY, hi = -INFINITY;
        if (p->fixed) {
            lo = p->range[2 * a], hi = p->range[2 * a + 1];
            if (p->log[a] && lo <= 0)
                return wf_error(WF_ERR_RANGE, "log %c axis needs a positive range, not %g..%g",
                                "xy"[a], lo, hi);
            lo = axis_t(p, a, lo), hi = axis_t(p, a, hi);
        } else {
            for (int i = 0; i < p->ns; i++) {
                const series *s = &p->s[i];
                for (int j = 0; j < s->n; j++) {
                    if (!usable(s->x[j], p->log[0]) || !usable(s->y[j], p->log[1])) continue;
                    double v = a ? s->y[j] : s->x[j];
                    extend(&lo, &hi, axis_t(p, a, v));
                    if (a && (s->style & WF_PLOT_ERRORBARS) && isfinite(s->e[j]))
                        for (int sg = -1; sg <= 1; sg += 2)
                            if (usable(v + sg * fabs(s->e[j]), p->log[1]))
                                extend(&lo, &hi, axis_t(p, 1, v + sg * fabs(s->e[j])));
                }
            }
            if (lo > hi) lo = 0, hi = 1;
            double pad = hi > lo ? 0.05 * (hi - lo) : lo != 0 ? 0.05 * fabs(lo) : 0.5;
            lo -= pad, hi += pad;
            if (!isfinite(hi - lo))
                return wf_error(WF_ERR_RANGE, "%c data span more than a double holds", "xy"[a]);
        }
        p->lo[a] = lo, p->hi[a] = hi;
        p->ntick[a] = p->log[a] ? log_ticks(lo, hi, p->tick[a], MAXTICKS)
                                : wf_plot_nice_ticks(lo, hi, 5, p->tick[a], MAXTICKS);
    }
    int yw = labels_width(p->tick[1], p->ntick[1]);
    p->T = 10 + (p->title ? 2 * FH + 10 : 0);
    p->B = p->h - 1 - (4 + 3 + FH + 8 + (p->xlabel ? FH + 6 : 0));
    p->L = 6 + (p->ylabel ? FH + 8 : 0) + yw + 3 + 4;
    p->R = p->w - 1 - 24;
    if (p->R - p->L < 20 || p->B - p->T < 20)
        return wf_error(WF_ERR_RANGE, "plot %dx%d too small for its labels", p->w, p->h);
    return WF_OK;
}

/* Pixel coordinate along axis a of a value already on the axis scale (log10 on log axes). */
static double to_px(const wf_plot *p, int a, double t)
{
    double f = (t - p->lo[a]) / (p->hi[a] - p->lo[a]);
    if (a == 0) return p->L + f * (p->R - p->L);
    if (p->inverty) f = 1 - f;
    return p->B - f * (p->B - p->T);
}

wf_status wf_plot_data_to_pixel(wf_plot *p, double x, double y, double *px, double *py)
{
    wf_status st = finish(p);
    if (st) return st;
    if (!usable(x, p->log[0]) || !usable(y, p->log[1]))
        return wf_error(WF_ERR_RANGE, "point (%g, %g) cannot be placed on the plot's axes", x, y);
    *px = to_px(p, 0, axis_t(p, 0, x));
    *py = to_px(p, 1, axis_t(p, 1, y));
    return WF_OK;
}

/* A series marker or legend sample centred on (x, y). */
static void marker(canvas *c, int x, int y, const unsigned char *col)
{
    fill(c, x - 2, y - 2, x + 2, y + 2, col);
}

static void draw_series(wf_plot *p, canvas *c, const series *s, const unsigned char *col)
{
    int lx = p->log[0], ly = p->log[1], have_prev = 0;
    double ppx = 0, ppy = 0;
    for (int j = 0; j < s->n; j++) {
        if (!usable(s->x[j], lx) || !usable(s->y[j], ly)) {
            have_prev = 0; /* the line breaks at a point it cannot place */
            continue;
        }
        double px = to_px(p, 0, axis_t(p, 0, s->x[j])), py = to_px(p, 1, axis_t(p, 1, s->y[j]));
        if ((s->style & WF_PLOT_LINE) && have_prev) line(c, ppx, ppy, px, py, col);
        if ((s->style & WF_PLOT_ERRORBARS) && isfinite(s->e[j])) {
            double e = fabs(s->e[j]), ylo = s->y[j] - e;
            double pl = usable(ylo, ly) ? to_px(p, 1, axis_t(p, 1, ylo)) : (p->inverty ? -1e7 : 1e7);
            double ph = to_px(p, 1, axis_t(p, 1, s->y[j] + e));
            line(c, px, pl, px, ph, col);
            line(c, px - 2, pl, px + 2, pl, col);
            line(c, px - 2, ph, px + 2, ph, col);
        }
        if ((s->style & WF_PLOT_MARKERS) && fabs(px) < 1e7 && fabs(py) < 1e7)
            marker(c, (int)lround(px), (int)lround(py), col);
        ppx = px, ppy = py, have_prev = 1;
    }
}

static void draw_legend(wf_plot *p, canvas *c)
{
    int n = 0, tw = 0;
    for (int i = 0; i < p->ns; i++)
        if (p->s[i].label) {
            n++;
            int w = text_width(p->s[i].label, 1);
            if (w > tw) tw = w;
        }
    if (!n) return;
    int bw = 6 + 20 + 6 + tw + 6, bh = 4 + n * (FH + 5) + 1;
    int x0 = p->R - 6 - bw, y0 = p->T + 6, k = 0;
    fill(c, x0, y0, x0 + bw, y0 + bh, white);
    rect(c, x0, y0, x0 + bw, y0 + bh, black);
    for (int i = 0; i < p->ns; i++) {
        const series *s = &p->s[i];
        if (!s->label) continue;
        int cy = y0 + 5 + k * (FH + 5) + FH / 2;
        const unsigned char *col = palette[i % NPALETTE];
        if (s->style & WF_PLOT_LINE) fill(c, x0 + 6, cy, x0 + 26, cy, col);
        if (s->style & (WF_PLOT_MARKERS | WF_PLOT_ERRORBARS)) marker(c, x0 + 16, cy, col);
        text(c, x0 + 32, cy - FH / 2, s->label, 1, 0, black);
        k++;
    }
}

wf_status wf_plot_write_png(wf_plot *p, const char *path)
{
    wf_status st = finish(p);
    if (st) {
        char why[512];
        snprintf(why, sizeof why, "%s", wf_error_message());
        return wf_error(st, "%s: %s", path ? path : "plot", why);
    }
    canvas c = {malloc((size_t)p->w * p->h * 3), p->w, p->h, 0, 0, 0, 0};
    if (!c.px) return wf_error(WF_ERR_NOMEM, "%s: no memory for a %dx%d plot", path, p->w, p->h);
    memset(c.px, 255, (size_t)p->w * p->h * 3);
    noclip(&c);
    for (int a = 0; a < 2; a++) {
        int q[MAXTICKS];
        for (int i = 0; i < p->ntick[a]; i++) {
            q[i] = (int)lround(to_px(p, a, axis_t(p, a, p->tick[a][i])));
            if (a == 0) fill(&c, q[i], p->T + 1, q[i], p->B - 1, grid);
            else fill(&c, p->L + 1, q[i], p->R - 1, q[i], grid);
        }
        axis_ticks(&c, p->tick[a], q, p->ntick[a], a, a ? p->L - 1 : p->B + 1);
    }
    c.cl = p->L, c.cr = p->R, c.ct = p->T, c.cb = p->B;
    for (int i = 0; i < p->ns; i++) draw_series(p, &c, &p->s[i], palette[i % NPALETTE]);
    noclip(&c);
    rect(&c, p->L, p->T, p->R, p->B, black);
    draw_legend(p, &c);
    int mid = (p->L + p->R) / 2;
    if (p->title) text(&c, mid - text_width(p->title, 2) / 2, 8, p->title, 2, 0, black);
    if (p->xlabel)
        text(&c, mid - text_width(p->xlabel, 1) / 2, p->B + 8 + FH + 6, p->xlabel, 1, 0, black);
    if (p->ylabel)
        text(&c, 6, (p->T + p->B) / 2 + text_width(p->ylabel, 1) / 2, p->ylabel, 1, 1, black);
    st = wf_png_write_rgb(path, c.px, c.w, c.h);
    free(c.px);
    return st;
}

void wf_plot_free(wf_plot *p)
{
    if (!p) return;
    for (int i = 0; i < p->ns; i++) {
        free(p->s[i].x), free(p->s[i].y), free(p->s[i].e), free(p->s[i].label);
    }
    free(p->s), free(p->title), free(p->xlabel), free(p->ylabel), free(p);
}

/* ---- maps -------------------------------------------------------------------------------------- */

/* Map side in pixels: whole pixels per cell when that fits 160..800, else stretched or sampled. */
static int map_side(int n, int scale)
{
    long s = (long)n * scale;
    return s < 160 ? 160 : s > 800 ? 800 : (int)s;
}

wf_status wf_plot_map_png(const float *data, int nx, int ny, double x0, double x1, double y0,
                          double y1, double vmin, double vmax, const char *title,
                          const char *xlabel, const char *ylabel, const char *cbar_label,
                          const char *path)
{
    const char *name = path ? path : "map";
    if (!data || nx < 1 || ny < 1 || !path)
        return wf_error(WF_ERR_INPUT, "%s: map of %dx%d cells without data or path", name, nx, ny);
    if (!(isfinite(x0) && isfinite(x1) && isfinite(y0) && isfinite(y1) && x0 != x1 && y0 != y1 &&
          isfinite(vmin) && isfinite(vmax) && vmin < vmax))
        return wf_error(WF_ERR_RANGE, "%s: map axes %g..%g, %g..%g or colour range %g..%g empty",
                        name, x0, x1, y0, y1, vmin, vmax);
    int big = nx > ny ? nx : ny, scale = big >= 512 ? 1 : 512 / big;
    int iw = map_side(nx, scale), ih = map_side(ny, scale);
    double xt[MAXTICKS], yt[MAXTICKS], ct[MAXTICKS];
    int nxt = wf_plot_nice_ticks(fmin(x0, x1), fmax(x0, x1), 5, xt, MAXTICKS);
    int nyt = wf_plot_nice_ticks(fmin(y0, y1), fmax(y0, y1), 5, yt, MAXTICKS);
    int nct = wf_plot_nice_ticks(vmin, vmax, 5, ct, MAXTICKS);
    int yw = labels_width(yt, nyt), cw = labels_width(ct, nct), q[MAXTICKS];

    /* frame at columns L and L+iw+1, rows T and T+ih+1; cells inside; bar frame from BX */
    int T = 10 + (title ? 2 * FH + 10 : 0), L = 6 + (ylabel ? FH + 8 : 0) + yw + 7;
    int BX = L + iw + 2 + 16, BW = 16, CX = BX + BW + 2 + 7 + cw + 8;
    int W = CX + (cbar_label ? FH : 0) + 10, H = T + ih + 2 + 4 + 3 + FH + 8 + (xlabel ? FH + 6 : 0);
    int tw = title ? text_width(title, 2) + 20 : 0;
    if (W < tw) W = tw;
    canvas c = {malloc((size_t)W * H * 3), W, H, 0, 0, 0, 0};
    if (!c.px) return wf_error(WF_ERR_NOMEM, "%s: no memory for a %dx%d map", name, W, H);
    memset(c.px, 255, (size_t)W * H * 3);
    noclip(&c);
    unsigned char col[3];
    for (int r = 0; r < ih; r++) {
        int iy = ny - 1 - (int)((long long)r * ny / ih);
        for (int k = 0; k < iw; k++) {
            float v = data[(size_t)iy * nx + (size_t)((long long)k * nx / iw)];
            if (!(v >= vmin)) continue; /* below vmin or NaN: left white */
            wf_plot_colormap((v - vmin) / (vmax - vmin), col);
            pset(&c, L + 1 + k, T + 1 + r, col);
        }
    }
    for (int r = 0; r < ih; r++) {
        wf_plot_colormap(ih > 1 ? 1.0 - (double)r / (ih - 1) : 1.0, col);
        fill(&c, BX + 1, T + 1 + r, BX + BW, T + 1 + r, col);
    }
    rect(&c, L, T, L + iw + 1, T + ih + 1, black);
    rect(&c, BX, T, BX + BW + 1, T + ih + 1, black);
    /* cell edges: x0 at the boundary between the frame and the first column, x1 after the last */
    for (int i = 0; i < nxt; i++) q[i] = (int)lround(L + 0.5 + (xt[i] - x0) / (x1 - x0) * iw);
    axis_ticks(&c, xt, q, nxt, 0, T + ih + 2);
    for (int i = 0; i < nyt; i++) q[i] = (int)lround(T + ih + 0.5 - (yt[i] - y0) / (y1 - y0) * ih);
    axis_ticks(&c, yt, q, nyt, 1, L - 1);
    for (int i = 0; i < nct; i++)
        q[i] = (int)lround(T + 1 + (1 - (ct[i] - vmin) / (vmax - vmin)) * (ih - 1));
    axis_ticks(&c, ct, q, nct, 2, BX + BW + 2);
    int mid = L + iw / 2, ymid = T + ih / 2;
    if (title) text(&c, (W - text_width(title, 2)) / 2, 8, title, 2, 0, black);
    if (xlabel) text(&c, mid - text_width(xlabel, 1) / 2, T + ih + 9 + FH + 6, xlabel, 1, 0, black);
    if (ylabel) text(&c, 6, ymid + text_width(ylabel, 1) / 2, ylabel, 1, 1, black);
    if (cbar_label) text(&c, CX, ymid + text_width(cbar_label, 1) / 2, cbar_label, 1, 1, black);
    wf_status st = wf_png_write_rgb(path, c.px, W, H);
    free(c.px);
    return st;
}
