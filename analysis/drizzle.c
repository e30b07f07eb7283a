#include "analysis/drizzle.h"

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#define MAXV 12 /* a quadrilateral clipped by four half-planes has at most 8 vertices */

/* Sutherland-Hodgman against one half-plane: keeps s * (coordinate axis) >= s * bound. */
static int clip(const double *px, const double *py, int n, int axis, double bound, double s,
                double *qx, double *qy)
{
    int m = 0;
    for (int k = 0; k < n; k++) {
        int l = (k + 1) % n;
        double a = s * ((axis ? py[k] : px[k]) - bound);
        double b = s * ((axis ? py[l] : px[l]) - bound);
        if (a >= 0) {
            qx[m] = px[k];
            qy[m] = py[k];
            m++;
        }
        if ((a >= 0) != (b >= 0)) {
            double t = a / (a - b);
            qx[m] = px[k] + t * (px[l] - px[k]);
            qy[m] = py[k] + t * (py[l] - py[k]);
            if (axis) qy[m] = bound; else qx[m] = bound; /* exactly on the line */
            m++;
        }
    }
    return m;
}

static double area(const double *x, const double *y, int n)
{
    double s = 0;
    for (int k = 0; k < n; k++) {
        int l = (k + 1) % n;
        s += x[k] * y[l] - x[l] * y[k];
    }
    return fabs(0.5 * s);
}

/* The part of polygon p between lo and hi along axis, into q (returns its vertex count). */
static int band(const double *px, const double *py, int n, int axis, double lo, double hi,
                double *qx, double *qy)
{
    double tx[MAXV], ty[MAXV];
    int m = clip(px, py, n, axis, lo, 1.0, tx, ty);
    if (m < 3) return 0;
    m = clip(tx, ty, m, axis, hi, -1.0, qx, qy);
    return m < 3 ? 0 : m;
}

double wf_drizzle_overlap(const double x[4], const double y[4], int i, int j)
{
    double rx[MAXV], ry[MAXV], qx[MAXV], qy[MAXV];
    int n = band(x, y, 4, 1, j - 0.5, j + 0.5, rx, ry);
    if (!n) return 0;
    n = band(rx, ry, n, 0, i - 0.5, i + 0.5, qx, qy);
    return n ? area(qx, qy, n) : 0;
}

wf_status wf_drizzle_tile_alloc(wf_drizzle_tile *t, int nx, int max_rows)
{
    memset(t, 0, sizeof *t);
    size_t n = (size_t)nx * (size_t)max_rows;
    t->nx = nx;
    t->sum = malloc(n * sizeof *t->sum);
    t->wht = malloc(n * sizeof *t->wht);
    t->var = malloc(n * sizeof *t->var);
    t->ctx = malloc(n * sizeof *t->ctx);
    t->last = malloc(n * sizeof *t->last);
    if (!t->sum || !t->wht || !t->var || !t->ctx || !t->last) {
        wf_drizzle_tile_free(t);
        return wf_error(WF_ERR_NOMEM, "drizzle: cannot allocate a tile of %d x %d output pixels", nx, max_rows);
    }
    return WF_OK;
}

void wf_drizzle_tile_reset(wf_drizzle_tile *t, int y0, int ny)
{
    size_t n = (size_t)t->nx * (size_t)ny;
    t->y0 = y0;
    t->ny = ny;
    memset(t->sum, 0, n * sizeof *t->sum);
    memset(t->wht, 0, n * sizeof *t->wht);
    memset(t->var, 0, n * sizeof *t->var);
    memset(t->ctx, 0, n * sizeof *t->ctx);
    memset(t->last, 0, n * sizeof *t->last);
}

void wf_drizzle_tile_free(wf_drizzle_tile *t)
{
    free(t->sum);
    free(t->wht);
    free(t->var);
    free(t->ctx);
    free(t->last);
    memset(t, 0, sizeof *t);
}

int wf_drizzle_drop(wf_drizzle_tile *t, const double x[4], const double y[4], double pixfrac,
                    double d, double w, double var_d, int32_t id)
{
    /* the drop's area, output pixels (shoelace of the quadrilateral, as drizzle's jaco) */
    double jaco = 0.5 * fabs((x[1] - x[3]) * (y[0] - y[2]) - (x[0] - x[2]) * (y[1] - y[3]));
    if (!(jaco > 0) || !isfinite(jaco)) return 0;
    double xmin = x[0], xmax = x[0], ymin = y[0], ymax = y[0];
    for (int k = 1; k < 4; k++) {
        xmin = fmin(xmin, x[k]);
        xmax = fmax(xmax, x[k]);
        ymin = fmin(ymin, y[k]);
        ymax = fmax(ymax, y[k]);
    }
    int i0 = (int)floor(xmin + 0.5), i1 = (int)floor(xmax + 0.5);
    int j0 = (int)floor(ymin + 0.5), j1 = (int)floor(ymax + 0.5);
    if (i0 < 0) i0 = 0;
    if (i1 > t->nx - 1) i1 = t->nx - 1;
    if (j0 < t->y0) j0 = t->y0;
    if (j1 > t->y0 + t->ny - 1) j1 = t->y0 + t->ny - 1;
    if (i0 > i1 || j0 > j1) return 0;
    double v = d * pixfrac * pixfrac / jaco;
    double var_v = var_d * (pixfrac * pixfrac / jaco) * (pixfrac * pixfrac / jaco);
    int hit = 0;
    for (int j = j0; j <= j1; j++) {
        double rx[MAXV], ry[MAXV];
        int n = band(x, y, 4, 1, j - 0.5, j + 0.5, rx, ry);
        if (!n) continue;
        size_t row = (size_t)(j - t->y0) * (size_t)t->nx;
        for (int i = i0; i <= i1; i++) {
            double qx[MAXV], qy[MAXV];
            int m = band(rx, ry, n, 0, i - 0.5, i + 0.5, qx, qy);
            if (!m) continue;
            double c = w * area(qx, qy, m) / jaco;
            if (!(c > 0)) continue;
            size_t o = row + (size_t)i;
            t->sum[o] += c * v;
            t->wht[o] += c;
            t->var[o] += c * c * var_v;
            if (t->last[o] != id) {
                t->last[o] = id;
                t->ctx[o]++;
            }
            hit = 1;
        }
    }
    return hit;
}

long wf_drizzle_add(wf_drizzle_tile *t, const wf_drizzle_block *b, double pixfrac,
                    uint32_t dq_mask, int32_t id)
{
    const double h = 0.5 * pixfrac;
    const int stride = b->nc + 2;
    /* corners in order around the drop: (-,-), (+,-), (+,+), (-,+) */
    static const int sx[4] = {-1, 1, 1, -1}, sy[4] = {-1, -1, 1, 1};
    long hits = 0;
    for (int r = 0; r < b->nr; r++)
        for (int c = 0; c < b->nc; c++) {
            size_t p = (size_t)r * (size_t)b->stride + (size_t)c;
            double d = b->sci[p], e = b->err[p];
            if ((b->dq[p] & dq_mask) || !isfinite(d) || !isfinite(e) || !(e > 0)) continue;
            double x[4], y[4];
            for (int k = 0; k < 4; k++) {
                /* bilinear between the centre and its neighbours towards the corner */
                ptrdiff_t c00 = (ptrdiff_t)(r + 1) * stride + (c + 1);
                ptrdiff_t c10 = c00 + sx[k], c01 = c00 + (ptrdiff_t)sy[k] * stride;
                ptrdiff_t c11 = c01 + sx[k];
                double w00 = (1 - h) * (1 - h), w10 = h * (1 - h), w01 = (1 - h) * h, w11 = h * h;
                x[k] = w00 * b->ox[c00] + w10 * b->ox[c10] + w01 * b->ox[c01] + w11 * b->ox[c11];
                y[k] = w00 * b->oy[c00] + w10 * b->oy[c10] + w01 * b->oy[c01] + w11 * b->oy[c11];
            }
            hits += wf_drizzle_drop(t, x, y, pixfrac, d, b->weight, e * e, id);
        }
    return hits;
}
