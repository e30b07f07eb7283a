/* PNG writer and plots (analysis/png.c, analysis/plot.c). Every image written is read back by a
 * decoder of its own here (chunk walk, each CRC recomputed with zlib's crc32, IDAT joined and
 * inflated with uncompress, all five row filters undone), and the checks use what that decoder
 * sees, never bytes the library computed:
 *  - signature, IHDR (size, depth 8, colour type 2), exact round trip of random pixels;
 *  - a horizontal series lands on the row wf_plot_data_to_pixel gives, in a saturated colour;
 *  - nothing but white and black (text, ticks) outside the frame, even with data beyond it;
 *  - automatic ranges are the finite data plus 5% (the frame found in the image), log axes
 *    skip non-positive data, non-finite points break a line;
 *  - a map's cells: vmin and vmax colours where expected, white below vmin, lightness rising;
 *  - tick rule: 1, 2, 5 x 10^k steps, inside the range, >= 4, evenly spaced (random ranges);
 *  - an unwritable path fails, names the path and leaves no file. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zlib.h>

#include "tests/testutil.h"
#include "analysis/plot.h"
#include "analysis/png.h"

/* ------------------------------------------------------------------ an independent decoder */

typedef struct {
    int w, h, depth, ctype, interlace;
    unsigned char *rgb; /* w*h*3 */
} image;

static uint32_t be32(const unsigned char *b)
{
    return (uint32_t)b[0] << 24 | (uint32_t)b[1] << 16 | (uint32_t)b[2] << 8 | b[3];
}

static int paeth(int a, int b, int c)
{
    int p = a + b - c, pa = abs(p - a), pb = abs(p - b), pc = abs(p - c);
    return pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
}

static image decode(const char *path)
{
    static const unsigned char sig[8] = {137, 80, 78, 71, 13, 10, 26, 10};
    image im = {0};
    size_t len;
    unsigned char *f = (unsigned char *)wf_test_slurp(path, &len);
    ck_assert_msg(f != NULL, "cannot read %s", path);
    ck_assert_msg(len >= 8 && memcmp(f, sig, 8) == 0, "%s: no PNG signature", path);
    unsigned char *idat = NULL;
    size_t nidat = 0, pos = 8;
    int seen_iend = 0, chunks = 0;
    while (pos + 12 <= len && !seen_iend) {
        uint32_t n = be32(f + pos);
        ck_assert_msg(pos + 12 + n <= len, "chunk %d overruns the file", chunks);
        const unsigned char *type = f + pos + 4, *data = f + pos + 8;
        uint32_t crc = (uint32_t)crc32(crc32(0L, Z_NULL, 0), type, 4 + n);
        ck_assert_msg(crc == be32(data + n), "chunk %d (%.4s): CRC %08x, file says %08x", chunks,
                      (const char *)type, crc, be32(data + n));
        if (chunks == 0) {
            ck_assert_msg(memcmp(type, "IHDR", 4) == 0 && n == 13, "first chunk is not IHDR");
            im.w = (int)be32(data);
            im.h = (int)be32(data + 4);
            im.depth = data[8];
            im.ctype = data[9];
            ck_assert_int_eq(data[10], 0);
            ck_assert_int_eq(data[11], 0);
            im.interlace = data[12];
        } else if (memcmp(type, "IDAT", 4) == 0) {
            idat = realloc(idat, nidat + n + 1);
            memcpy(idat + nidat, data, n);
            nidat += n;
        } else if (memcmp(type, "IEND", 4) == 0) {
            ck_assert_int_eq(n, 0);
            seen_iend = 1;
        }
        pos += 12 + n;
        chunks++;
    }
    ck_assert_msg(seen_iend && pos == len, "%s: no IEND or bytes after it", path);
    ck_assert_int_eq(im.depth, 8);
    ck_assert_int_eq(im.ctype, 2);
    ck_assert_int_eq(im.interlace, 0);
    size_t stride = (size_t)im.w * 3;
    uLongf rawlen = (uLongf)(im.h * (stride + 1));
    unsigned char *raw = malloc(rawlen + 1);
    uLongf got = rawlen;
    ck_assert_int_eq(uncompress(raw, &got, idat, (uLong)nidat), Z_OK);
    ck_assert_uint_eq(got, rawlen);
    im.rgb = malloc(stride * im.h);
    for (int y = 0; y < im.h; y++) {
        int ft = raw[y * (stride + 1)];
        ck_assert_msg(ft <= 4, "row %d: filter %d", y, ft);
        const unsigned char *src = raw + y * (stride + 1) + 1;
        unsigned char *row = im.rgb + y * stride, *up = y ? row - stride : NULL;
        for (size_t i = 0; i < stride; i++) {
            int a = i >= 3 ? row[i - 3] : 0, b = up ? up[i] : 0, c = up && i >= 3 ? up[i - 3] : 0;
            int pred = ft == 1 ? a : ft == 2 ? b : ft == 3 ? (a + b) / 2 : ft == 4 ? paeth(a, b, c) : 0;
            row[i] = (unsigned char)(src[i] + pred);
        }
    }
    free(raw);
    free(idat);
    free(f);
    return im;
}

static const unsigned char *at(const image *im, int x, int y)
{
    ck_assert_msg(x >= 0 && y >= 0 && x < im->w && y < im->h, "pixel (%d,%d) outside %dx%d", x, y,
                  im->w, im->h);
    return im->rgb + 3 * ((size_t)y * im->w + x);
}

static int is_white(const unsigned char *c) { return c[0] == 255 && c[1] == 255 && c[2] == 255; }
static int is_black(const unsigned char *c) { return c[0] == 0 && c[1] == 0 && c[2] == 0; }
/* A series colour: channels far apart, unlike white, black, grey grid and text. */
static int is_saturated(const unsigned char *c)
{
    int mx = c[0] > c[1] ? c[0] : c[1], mn = c[0] < c[1] ? c[0] : c[1];
    mx = c[2] > mx ? c[2] : mx;
    mn = c[2] < mn ? c[2] : mn;
    return mx - mn >= 60;
}

/* The frame: the longest run of black pixels along a row is its top or bottom edge (with the
 * corner ticks); of that run's columns, the first and last with a long vertical black run are
 * its left and right edges; the first and last rows black from left to right edge are its top
 * and bottom. Text and ticks are short. */
static void find_frame(const image *im, int *l, int *t, int *r, int *b)
{
    int best = 0, by = 0, x0 = 0, x1 = 0;
    for (int y = 0; y < im->h; y++)
        for (int x = 0, run = 0; x < im->w; x++) {
            run = is_black(at(im, x, y)) ? run + 1 : 0;
            if (run > best) best = run, by = y, x1 = x, x0 = x - run + 1;
        }
    *l = *r = -1;
    for (int x = x0; x <= x1; x++) {
        int y0 = by, y1 = by;
        while (y0 > 0 && is_black(at(im, x, y0 - 1))) y0--;
        while (y1 < im->h - 1 && is_black(at(im, x, y1 + 1))) y1++;
        if (y1 - y0 < 50) continue;
        if (*l < 0) *l = x, *t = y0, *b = y1;
        *r = x;
    }
    ck_assert_msg(*l >= 0 && *r - *l > 50, "no frame found");
    for (int y = *t, first = 1, full; y <= *b + 1; y++) {
        for (full = 1, x0 = *l; full && x0 <= *r && y <= *b; x0++) full = is_black(at(im, x0, y));
        if (full && first) *t = y, first = 0;
        if (full && y <= *b) x1 = y;
    }
    *b = x1;
    ck_assert_msg(*b - *t > 50, "no frame found");
}

static char *path_in(const char *dir, const char *name)
{
    static char buf[4][4096];
    static int slot;
    char *p = buf[slot++ % 4];
    snprintf(p, sizeof buf[0], "%s/%s", dir, name);
    return p;
}

static int exists(const char *path) { return access(path, F_OK) == 0; }

/* ------------------------------------------------------------------ PNG */

START_TEST(test_png_roundtrip)
{
    const char *dir = wf_test_tmpdir();
    ck_assert_ptr_nonnull(dir);
    static const int sizes[][2] = {{1, 1}, {7, 5}, {123, 45}, {300, 200}};
    srand(12345);
    for (int k = 0; k < 4; k++) {
        int w = sizes[k][0], h = sizes[k][1];
        unsigned char *rgb = malloc((size_t)w * h * 3);
        /* random noise, and smooth gradients in the lower half so other filters win too */
        for (int i = 0; i < w * h * 3; i++)
            rgb[i] = i / (w * 3) < h / 2 ? (unsigned char)(rand() & 255)
                                          : (unsigned char)((i % (w * 3)) / 3 + 2 * (i / (w * 3)) + i % 3);
        const char *path = path_in(dir, "rt.png");
        ck_assert_int_eq(wf_png_write_rgb(path, rgb, w, h), WF_OK);
        image im = decode(path);
        ck_assert_int_eq(im.w, w);
        ck_assert_int_eq(im.h, h);
        ck_assert_msg(memcmp(im.rgb, rgb, (size_t)w * h * 3) == 0, "%dx%d differs after decoding", w, h);
        ck_assert_msg(!exists(path_in(dir, "rt.png.tmp")), "temporary file left behind");
        free(im.rgb);
        free(rgb);
    }
}
END_TEST

START_TEST(test_unwritable_path)
{
    const char *dir = wf_test_tmpdir();
    unsigned char rgb[12] = {0};
    const char *path = path_in(dir, "no-such-dir/x.png");
    ck_assert_int_eq(wf_png_write_rgb(path, rgb, 2, 2), WF_ERR_IO);
    ck_assert_msg(strstr(wf_error_message(), path) != NULL, "message lacks the path: %s",
                  wf_error_message());
    ck_assert_int_eq(wf_png_write_rgb(path_in(dir, "bad.png"), rgb, 0, 2), WF_ERR_RANGE);

    wf_plot *p;
    ck_assert_int_eq(wf_plot_create(200, 150, "t", "x", "y", &p), WF_OK);
    double x[2] = {0, 1}, y[2] = {0, 1};
    ck_assert_int_eq(wf_plot_series(p, x, y, NULL, 2, "s", WF_PLOT_LINE), WF_OK);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_ERR_IO);
    ck_assert_msg(strstr(wf_error_message(), path) != NULL, "%s", wf_error_message());
    wf_plot_free(p);
    float m[4] = {1, 2, 3, 4};
    ck_assert_int_eq(wf_plot_map_png(m, 2, 2, 0, 1, 0, 1, 0, 4, "m", "x", "y", "c", path), WF_ERR_IO);
    ck_assert_msg(strstr(wf_error_message(), path) != NULL, "%s", wf_error_message());

    /* nothing appeared: neither the target nor its temporary, in the missing folder or beside */
    ck_assert(!exists(path_in(dir, "no-such-dir")));
    ck_assert(!exists(path_in(dir, "bad.png")));
    ck_assert(!exists(path_in(dir, "bad.png.tmp")));
}
END_TEST

/* ------------------------------------------------------------------ plots */

START_TEST(test_line_on_its_row)
{
    const char *dir = wf_test_tmpdir(), *path = path_in(dir, "line.png");
    wf_plot *p;
    ck_assert_int_eq(wf_plot_create(640, 480, "Horizontal", "x (s)", "y (e-/s)", &p), WF_OK);
    double x[2] = {1, 9}, y[2] = {3.7, 3.7}, zx[2] = {0, 10}, zy[2] = {0, 10};
    ck_assert_int_eq(wf_plot_series(p, zx, zy, NULL, 2, NULL, WF_PLOT_MARKERS), WF_OK);
    ck_assert_int_eq(wf_plot_series(p, x, y, NULL, 2, NULL, WF_PLOT_LINE), WF_OK);
    double px1, py1, px9, py9;
    ck_assert_int_eq(wf_plot_data_to_pixel(p, 1, 3.7, &px1, &py1), WF_OK);
    ck_assert_int_eq(wf_plot_data_to_pixel(p, 9, 3.7, &px9, &py9), WF_OK);
    ck_assert_double_eq(py1, py9);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
    wf_plot_free(p);

    image im = decode(path);
    ck_assert_int_eq(im.w, 640);
    ck_assert_int_eq(im.h, 480);
    int row = (int)lround(py1), c0 = (int)lround(px1), c1 = (int)lround(px9);
    const unsigned char *first = at(&im, c0, row);
    ck_assert_msg(is_saturated(first), "(%d,%d) is %d,%d,%d", c0, row, first[0], first[1], first[2]);
    for (int x0 = c0; x0 <= c1; x0++) {
        const unsigned char *c = at(&im, x0, row);
        ck_assert_msg(memcmp(c, first, 3) == 0, "line broken at column %d", x0);
        /* one pixel thick, so the rows beside it are not that colour */
        ck_assert(memcmp(at(&im, x0, row - 2), first, 3) != 0);
        ck_assert(memcmp(at(&im, x0, row + 2), first, 3) != 0);
    }
    /* it ends where the data end */
    ck_assert(memcmp(at(&im, c0 - 3, row), first, 3) != 0);
    ck_assert(memcmp(at(&im, c1 + 3, row), first, 3) != 0);
    free(im.rgb);
}
END_TEST

/* Fixed ranges map linearly (or log-linearly) onto the frame found in the image. */
START_TEST(test_pixel_mapping)
{
    const char *dir = wf_test_tmpdir(), *path = path_in(dir, "map.png");
    for (int mode = 0; mode < 3; mode++) { /* linear, inverted y, log x + log y */
        wf_plot *p;
        ck_assert_int_eq(wf_plot_create(500, 400, "m", "x", "y", &p), WF_OK);
        double lo = mode == 2 ? 1 : 20, hi = mode == 2 ? 1000 : 30;
        ck_assert_int_eq(wf_plot_set_range(p, lo, hi, lo, hi), WF_OK);
        if (mode == 1) wf_plot_invert_y(p, 1);
        if (mode == 2) wf_plot_set_log(p, 1, 1);
        ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
        image im = decode(path);
        int l, t, r, b;
        find_frame(&im, &l, &t, &r, &b);
        double ax, ay, bx, by, mx, my;
        double mid = mode == 2 ? sqrt(lo * hi) : 0.5 * (lo + hi);
        ck_assert_int_eq(wf_plot_data_to_pixel(p, lo, lo, &ax, &ay), WF_OK);
        ck_assert_int_eq(wf_plot_data_to_pixel(p, hi, hi, &bx, &by), WF_OK);
        ck_assert_int_eq(wf_plot_data_to_pixel(p, mid, mid, &mx, &my), WF_OK);
        ck_assert_double_eq_tol(ax, l, 1e-9);
        ck_assert_double_eq_tol(bx, r, 1e-9);
        ck_assert_double_eq_tol(ay, (mode == 1 ? t : b), 1e-9);
        ck_assert_double_eq_tol(by, (mode == 1 ? b : t), 1e-9);
        ck_assert_double_eq_tol(mx, 0.5 * (l + r), 1e-9);
        ck_assert_double_eq_tol(my, 0.5 * (t + b), 1e-9);
        if (mode == 2) {
            ck_assert_int_eq(wf_plot_data_to_pixel(p, -1, 10, &mx, &my), WF_ERR_RANGE);
            ck_assert_int_eq(wf_plot_set_range(p, -1, 10, 1, 10), WF_OK);
            ck_assert_int_eq(wf_plot_write_png(p, path_in(dir, "neg.png")), WF_ERR_RANGE);
            ck_assert(!exists(path_in(dir, "neg.png")));
        }
        free(im.rgb);
        wf_plot_free(p);
    }
}
END_TEST

/* Series reaching far beyond fixed ranges (lines, markers, error bars, legend) stay inside the
 * frame: outside it every pixel is white or the black of text and ticks, and the margin right
 * of the frame (where no text goes) is all white. */
START_TEST(test_outside_frame)
{
    const char *dir = wf_test_tmpdir(), *path = path_in(dir, "clip.png");
    wf_plot *p;
    ck_assert_int_eq(wf_plot_create(600, 420, "Clipping", "time (d)", "magnitude", &p), WF_OK);
    ck_assert_int_eq(wf_plot_set_range(p, 0, 10, 20, 25), WF_OK);
    wf_plot_invert_y(p, 1);
    enum { N = 200 };
    double x[N], y[N], e[N];
    for (int i = 0; i < N; i++) {
        x[i] = -5 + 20.0 * i / (N - 1);
        y[i] = 22.5 + 6 * sin(x[i]);
        e[i] = 0.8 + (i % 7) * 0.5;
    }
    x[10] = 1e300, y[20] = -1e300;
    ck_assert_int_eq(wf_plot_series(p, x, y, e, N, "sine", WF_PLOT_LINE | WF_PLOT_MARKERS | WF_PLOT_ERRORBARS), WF_OK);
    for (int i = 0; i < N; i++) y[i] = 22 + 0.3 * i;
    ck_assert_int_eq(wf_plot_series(p, x, y, NULL, N, "ramp", WF_PLOT_LINE), WF_OK);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
    wf_plot_free(p);

    image im = decode(path);
    int l, t, r, b, inside_colour = 0;
    find_frame(&im, &l, &t, &r, &b);
    for (int y0 = 0; y0 < im.h; y0++)
        for (int x0 = 0; x0 < im.w; x0++) {
            const unsigned char *c = at(&im, x0, y0);
            if (x0 >= l && x0 <= r && y0 >= t && y0 <= b) {
                inside_colour += is_saturated(c);
                continue;
            }
            ck_assert_msg(is_white(c) || is_black(c), "(%d,%d) outside the frame is %d,%d,%d", x0,
                          y0, c[0], c[1], c[2]);
            if (x0 > r + 12) ck_assert_msg(is_white(c), "right margin (%d,%d) not white", x0, y0);
        }
    ck_assert_msg(inside_colour > 500, "only %d coloured pixels drawn", inside_colour);
    /* the title, the labels and the tick labels are there: black pixels above, below, left */
    int above = 0, below = 0, left = 0;
    for (int y0 = 0; y0 < im.h; y0++)
        for (int x0 = 0; x0 < im.w; x0++)
            if (is_black(at(&im, x0, y0))) {
                above += y0 < t;
                below += y0 > b + 5;
                left += x0 < l - 5;
            }
    ck_assert(above > 20 && below > 20 && left > 20);
    free(im.rgb);
}
END_TEST

/* Automatic ranges come from finite (and, on log axes, positive) data plus 5% each side; an
 * infinite or NaN coordinate neither crashes nor stretches the range, and breaks the line. */
START_TEST(test_nonfinite_and_auto_range)
{
    const char *dir = wf_test_tmpdir(), *path = path_in(dir, "nan.png");
    wf_plot *p;
    ck_assert_int_eq(wf_plot_create(500, 400, NULL, NULL, NULL, &p), WF_OK);
    double x[] = {0, 1, 2.3, 3.6, 4.6, INFINITY, NAN, 2};
    double y[] = {1, 1, NAN, 6, 6, 3, 2, -INFINITY};
    double e[] = {0.1, NAN, 0.1, INFINITY, 0.1, 0.1, 0.1, 0.1};
    ck_assert_int_eq(wf_plot_series(p, x, y, e, 8, "data", WF_PLOT_LINE | WF_PLOT_ERRORBARS), WF_OK);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
    image im = decode(path);
    int l, t, r, b;
    find_frame(&im, &l, &t, &r, &b);
    /* finite x 0..4.6, y 1..6 widened by error bars to 0.9..6.1, then by 5% */
    double x0 = -0.23, x1 = 4.83, y0 = 0.9 - 0.26, y1 = 6.1 + 0.26, px, py;
    ck_assert_int_eq(wf_plot_data_to_pixel(p, x0, y0, &px, &py), WF_OK);
    ck_assert_double_eq_tol(px, l, 1e-6);
    ck_assert_double_eq_tol(py, b, 1e-6);
    ck_assert_int_eq(wf_plot_data_to_pixel(p, x1, y1, &px, &py), WF_OK);
    ck_assert_double_eq_tol(px, r, 1e-6);
    ck_assert_double_eq_tol(py, t, 1e-6);
    /* drawn segment (0,1)-(1,1); none across the NaN from (1,1) to (3.6,6) */
    ck_assert_int_eq(wf_plot_data_to_pixel(p, 0.5, 1, &px, &py), WF_OK);
    ck_assert(is_saturated(at(&im, (int)lround(px), (int)lround(py))));
    ck_assert_int_eq(wf_plot_data_to_pixel(p, 2.3, 3.5, &px, &py), WF_OK);
    for (int dy = -3; dy <= 3; dy++)
        for (int dx = -3; dx <= 3; dx++)
            ck_assert(!is_saturated(at(&im, (int)lround(px) + dx, (int)lround(py) + dy)));
    free(im.rgb);
    wf_plot_free(p);

    /* log x: the non-positive points are dropped, the range is 1..100 plus 5% in decades */
    ck_assert_int_eq(wf_plot_create(500, 400, "log", "x", "y", &p), WF_OK);
    wf_plot_set_log(p, 1, 0);
    double lx[] = {-1, 0, 1, 10, 100}, ly[] = {5, 5, 1, 2, 3};
    ck_assert_int_eq(wf_plot_series(p, lx, ly, NULL, 5, NULL, WF_PLOT_MARKERS), WF_OK);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
    im = decode(path);
    find_frame(&im, &l, &t, &r, &b);
    ck_assert_int_eq(wf_plot_data_to_pixel(p, pow(10, -0.1), 3 + 0.1, &px, &py), WF_OK);
    ck_assert_double_eq_tol(px, l, 1e-6);
    ck_assert_double_eq_tol(py, t, 1e-6);
    ck_assert_int_eq(wf_plot_data_to_pixel(p, pow(10, 2.1), 1 - 0.1, &px, &py), WF_OK);
    ck_assert_double_eq_tol(px, r, 1e-6);
    ck_assert_double_eq_tol(py, b, 1e-6);
    free(im.rgb);
    wf_plot_free(p);

    /* nothing finite at all: still a plot */
    ck_assert_int_eq(wf_plot_create(300, 200, "empty", NULL, NULL, &p), WF_OK);
    double nx[2] = {NAN, INFINITY}, ny[2] = {1, NAN};
    ck_assert_int_eq(wf_plot_series(p, nx, ny, NULL, 2, "none", WF_PLOT_LINE | WF_PLOT_MARKERS), WF_OK);
    ck_assert_int_eq(wf_plot_write_png(p, path), WF_OK);
    wf_plot_free(p);
}
END_TEST

START_TEST(test_bad_arguments)
{
    wf_plot *p;
    ck_assert_int_eq(wf_plot_create(10, 400, "t", NULL, NULL, &p), WF_ERR_RANGE);
    ck_assert_ptr_null(p);
    ck_assert_int_eq(wf_plot_create(400, 300, "t", NULL, NULL, &p), WF_OK);
    double x[1] = {1};
    ck_assert_int_eq(wf_plot_series(p, x, x, NULL, 1, "e", WF_PLOT_ERRORBARS), WF_ERR_INPUT);
    ck_assert_int_eq(wf_plot_series(p, x, x, NULL, 1, "e", 0), WF_ERR_INPUT);
    ck_assert_int_eq(wf_plot_series(p, NULL, x, NULL, 1, "e", WF_PLOT_LINE), WF_ERR_INPUT);
    ck_assert_int_eq(wf_plot_set_range(p, 1, 1, 0, 1), WF_ERR_RANGE);
    ck_assert_int_eq(wf_plot_set_range(p, 0, 1, 0, NAN), WF_ERR_RANGE);
    wf_plot_free(p);
    wf_plot_free(NULL);
    float m[1] = {1};
    const char *path = path_in(wf_test_tmpdir(), "m.png");
    ck_assert_int_eq(wf_plot_map_png(m, 1, 1, 0, 1, 0, 1, 2, 2, NULL, NULL, NULL, NULL, path), WF_ERR_RANGE);
    ck_assert_int_eq(wf_plot_map_png(m, 0, 1, 0, 1, 0, 1, 0, 2, NULL, NULL, NULL, NULL, path), WF_ERR_INPUT);
    ck_assert(!exists(path));
}
END_TEST

/* ------------------------------------------------------------------ maps */

static double lightness(const unsigned char *c) { return 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]; }

START_TEST(test_map_cells)
{
    const char *dir = wf_test_tmpdir(), *path = path_in(dir, "cov.png");
    enum { NX = 5, NY = 3 };
    const double vmin = 1, vmax = 9;
    float d[NY][NX] = {{0, 1, 2, 3, 4}, /* iy = 0: the bottom row */
                       {5, 6, 7, 8, 9},
                       {-3, NAN, 1, 100, 9}};
    ck_assert_int_eq(wf_plot_map_png(&d[0][0], NX, NY, 75, 65, -55, -50, vmin, vmax, "Coverage",
                                     "RA (°)", "Dec (°)", "visits", path), WF_OK);
    image im = decode(path);
    int l, t, r, b;
    find_frame(&im, &l, &t, &r, &b);
    int iw = r - l - 1, ih = b - t - 1;
    unsigned char cmin[3], cmax[3];
    wf_plot_colormap(0, cmin);
    wf_plot_colormap(1, cmax);
    ck_assert(memcmp(cmin, cmax, 3) != 0 && lightness(cmax) > lightness(cmin) + 100);
    const unsigned char *cell[NY][NX];
    for (int iy = 0; iy < NY; iy++)
        for (int ix = 0; ix < NX; ix++) {
            int x0 = l + 1 + (int)((ix + 0.5) * iw / NX), y0 = t + 1 + (int)((NY - 1 - iy + 0.5) * ih / NY);
            cell[iy][ix] = at(&im, x0, y0);
            /* cells are uniform: the pixel a third of a cell away has the same colour */
            ck_assert(memcmp(at(&im, x0 + iw / NX / 3, y0 - ih / NY / 3), cell[iy][ix], 3) == 0);
        }
    ck_assert(is_white(cell[0][0]));  /* 0 < vmin */
    ck_assert(is_white(cell[2][0]));  /* negative */
    ck_assert(is_white(cell[2][1]));  /* NaN */
    ck_assert(memcmp(cell[0][1], cmin, 3) == 0);
    ck_assert(memcmp(cell[2][2], cmin, 3) == 0);
    ck_assert(memcmp(cell[1][4], cmax, 3) == 0);
    ck_assert(memcmp(cell[2][4], cmax, 3) == 0);
    ck_assert(memcmp(cell[2][3], cmax, 3) == 0); /* above vmax: clamped */
    /* values 1..9 in order get lighter step by step */
    const unsigned char *prev = cell[0][1];
    for (int v = 2; v <= 9; v++) {
        const unsigned char *c = cell[(v) / 5][(v) % 5];
        ck_assert_msg(lightness(c) > lightness(prev), "value %d not lighter than %d", v, v - 1);
        prev = c;
    }
    /* x0 = 75 is the left edge and x1 = 65 the right: the tick marks of 74 and 70 hang below
     * the frame a tenth and a half of the way across */
    for (int k = 0; k < 2; k++) {
        int c = (int)lround(l + 0.5 + (k ? 0.5 : 0.1) * iw), hit = 0;
        for (int dx = -1; dx <= 1; dx++) hit |= is_black(at(&im, c + dx, b + 2));
        ck_assert_msg(hit, "no tick mark below column %d", c);
        ck_assert(!is_black(at(&im, c - 6, b + 2)) && !is_black(at(&im, c + 6, b + 2)));
    }
    /* the colour bar right of the map holds both ends of the scale */
    int seen_min = 0, seen_max = 0;
    for (int y0 = t; y0 <= b; y0++)
        for (int x0 = r + 1; x0 < im.w; x0++) {
            seen_min |= memcmp(at(&im, x0, y0), cmin, 3) == 0;
            seen_max |= memcmp(at(&im, x0, y0), cmax, 3) == 0;
        }
    ck_assert(seen_min && seen_max);
    free(im.rgb);

    /* a map larger than 800 cells a side is sampled, not refused */
    enum { BIG = 1000 };
    float *big = malloc(sizeof(float) * BIG * 20);
    for (int i = 0; i < BIG * 20; i++) big[i] = (float)(i % BIG);
    ck_assert_int_eq(wf_plot_map_png(big, BIG, 20, 0, 1, 0, 1, 0, BIG - 1, NULL, NULL, NULL, NULL, path), WF_OK);
    im = decode(path);
    find_frame(&im, &l, &t, &r, &b);
    ck_assert_int_eq(r - l - 1, 800);
    ck_assert(lightness(at(&im, r - 1, (t + b) / 2)) > lightness(at(&im, l + 1, (t + b) / 2)));
    free(im.rgb);
    free(big);
}
END_TEST

/* ------------------------------------------------------------------ ticks */

static void check_ticks(double lo, double hi, int target)
{
    double t[64];
    int n = wf_plot_nice_ticks(lo, hi, target, t, 64);
    ck_assert_msg(n >= 4 && n >= target, "[%g, %g]: %d ticks", lo, hi, n);
    double step = (t[n - 1] - t[0]) / (n - 1);
    double mant = step / pow(10, floor(log10(step)));
    ck_assert_msg(fabs(mant - 1) < 1e-6 || fabs(mant - 2) < 1e-6 || fabs(mant - 5) < 1e-6 ||
                      fabs(mant - 10) < 1e-6,
                  "[%g, %g]: step %g", lo, hi, step);
    double tol = 1e-9 * (hi - lo);
    for (int i = 0; i < n; i++) {
        ck_assert_msg(t[i] >= lo - tol && t[i] <= hi + tol, "[%g, %g]: tick %g outside", lo, hi, t[i]);
        double m = t[i] / step;
        ck_assert_msg(fabs(m - nearbyint(m)) < 1e-6, "[%g, %g]: tick %g not a multiple of %g", lo,
                      hi, t[i], step);
        if (i) ck_assert_msg(fabs(t[i] - t[i - 1] - step) < 1e-6 * step, "[%g, %g]: uneven", lo, hi);
    }
    /* the step is the largest nice one giving that many: the next larger leaves fewer */
    double next = fabs(mant - 1) < 1e-6 ? 2 * step : fabs(mant - 2) < 1e-6 ? 2.5 * step : 2 * step;
    int want = target > 4 ? target : 4;
    ck_assert_msg(floor(hi / next) - ceil(lo / next) + 1 < want, "[%g, %g]: step %g too fine", lo, hi, step);
}

START_TEST(test_nice_ticks)
{
    static const double fixed[][2] = {{0, 1}, {-1, 1}, {1, 10}, {0.1, 0.35}, {99, 101},
                                      {-5e-9, 3e-9}, {20, 25}, {-0.23, 4.83}, {1e6, 3e6}};
    for (size_t i = 0; i < sizeof fixed / sizeof fixed[0]; i++) check_ticks(fixed[i][0], fixed[i][1], 5);
    double t[8];
    ck_assert_int_eq(wf_plot_nice_ticks(0, 1, 5, t, 8), 6); /* 0, 0.2, ..., 1 */
    ck_assert_double_eq_tol(t[1], 0.2, 1e-15);
    srand(777);
    for (int k = 0; k < 20000; k++) {
        double u1 = rand() / (double)RAND_MAX, u2 = rand() / (double)RAND_MAX;
        double span = pow(10, -8 + 16 * u1), lo = span * (-40 + 80 * u2) * (k % 3 ? 1 : 25);
        check_ticks(lo, lo + span, 4 + k % 5);
    }
    ck_assert_int_eq(wf_plot_nice_ticks(1, 1, 5, t, 8), 0);
    ck_assert_int_eq(wf_plot_nice_ticks(2, 1, 5, t, 8), 0);
    ck_assert_int_eq(wf_plot_nice_ticks(NAN, 1, 5, t, 8), 0);
    ck_assert_int_eq(wf_plot_nice_ticks(0, INFINITY, 5, t, 8), 0);
    ck_assert_int_eq(wf_plot_nice_ticks(0, 1, 5, t, 3), 3); /* never past max */
}
END_TEST

static Suite *plot_suite(void)
{
    Suite *s = suite_create("plot");
    TCase *tc = tcase_create("core");
    tcase_set_timeout(tc, 120);
    tcase_add_test(tc, test_png_roundtrip);
    tcase_add_test(tc, test_unwritable_path);
    tcase_add_test(tc, test_line_on_its_row);
    tcase_add_test(tc, test_pixel_mapping);
    tcase_add_test(tc, test_outside_frame);
    tcase_add_test(tc, test_nonfinite_and_auto_range);
    tcase_add_test(tc, test_bad_arguments);
    tcase_add_test(tc, test_map_cells);
    tcase_add_test(tc, test_nice_ticks);
    suite_add_tcase(s, tc);
    return s;
}

int main(void) { return wf_test_main(plot_suite()); }
