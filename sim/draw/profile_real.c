/* Without a PSF: every pixel is the profile's integral over it, in real space. Pixels near
 * the centre by a polar fan (the radial integral is the enclosed light, so the cusp needs no
 * quadrature), the others by Gauss-Legendre; knots as delta functions. The surface
 * brightness also serves the Fourier draw's wf_profile_dewrap (sim/draw/profile_fold.c). */
#include <math.h>
#include <stddef.h>
#include <stdlib.h>

#include "sim/draw/profile.h"
#include "sim/draw/profile_int.h"

/* Surface brightness of the smooth galaxy (flux per arcsec^2) at (x, y) arcsec from it. */
double wf_profile_smooth_density(const wf_draw_job *jb, const wf_sersic_table *t, double x,
                                 double y)
{
    const double(*ai)[2] = jb->shape.ainv;
    double r = hypot(ai[0][0] * x + ai[0][1] * y, ai[1][0] * x + ai[1][1] * y), d = 0.0;
    if (jb->fb > 0.0)
        d += jb->fb * t->dev_norm / (jb->re * jb->re) * exp(-t->b * sqrt(sqrt(r / jb->re)));
    if (jb->fd > 0.0) d += jb->fd / (2.0 * M_PI * jb->r0 * jb->r0) * exp(-r / jb->r0);
    return d;
}

/* Light of the smooth round galaxy within radius r, as a fraction of its flux (bulge and
 * smooth disk only; knots are drawn apart). */
static double smooth_enclosed(const wf_draw_job *jb, const wf_sersic_table *t, double r)
{
    if (!(r < INFINITY)) return jb->fb + jb->fd;
    double e = 0.0;
    if (jb->fb > 0.0) {
        double x = t->b * sqrt(sqrt(r / jb->re)), term = exp(-x), q = 0.0;
        for (int k = 0; k < 8; k++) {
            q += term;
            term *= x / (k + 1);
        }
        e += jb->fb * (1.0 - q);
    }
    if (jb->fd > 0.0) {
        double x = r / jb->r0;
        e += jb->fd * (-expm1(-x) - x * exp(-x));
    }
    return e;
}

static const double gl2[2][2] = {{-0.5773502691896258, 1.0}, {0.5773502691896258, 1.0}};
static const double gl4[4][2] = {{-0.8611363115940526, 0.3478548451374538},
                                 {-0.3399810435848563, 0.6521451548625461},
                                 {0.3399810435848563, 0.6521451548625461},
                                 {0.8611363115940526, 0.3478548451374538}};
static const double gl8[8][2] = {{-0.9602898564975363, 0.1012285362903763},
                                 {-0.7966664774136267, 0.2223810344533745},
                                 {-0.5255324099163290, 0.3137066458778873},
                                 {-0.1834346424956498, 0.3626837833783620},
                                 {0.1834346424956498, 0.3626837833783620},
                                 {0.5255324099163290, 0.3137066458778873},
                                 {0.7966664774136267, 0.2223810344533745},
                                 {0.9602898564975363, 0.1012285362903763}};

typedef struct fan {
    const wf_draw_job *jb;
    const wf_sersic_table *t;
    double d, phi; /* the edge's line: distance from the centre and direction of its foot */
} fan;

static double fan_f(const fan *f, double th)
{
    double c = cos(th - f->phi);
    return c > 0.0 ? smooth_enclosed(f->jb, f->t, f->d / c) : f->jb->fb + f->jb->fd;
}

/* Gauss-Kronrod 7-15 on [a, b]; *err is |K15 - G7|. */
static double gk15(const fan *f, double a, double b, double *err)
{
    static const double xk[8] = {0.991455371120812639, 0.949107912342758525, 0.864864423359769073,
                                 0.741531185599394440, 0.586087235467691130, 0.405845151377397167,
                                 0.207784955007898468, 0.0};
    static const double wk[8] = {0.022935322010529225, 0.063092092629978553, 0.104790010322250184,
                                 0.140653259715525919, 0.169004726639267903, 0.190350578064785410,
                                 0.204432940075298892, 0.209482141084727828};
    static const double wg[4] = {0.129484966168869693, 0.279705391489276668, 0.381830050505118945,
                                 0.417959183673469388};
    double c = 0.5 * (a + b), h = 0.5 * (b - a);
    double f0 = fan_f(f, c), k = wk[7] * f0, g = wg[3] * f0;
    for (int i = 0; i < 7; i++) {
        double v = fan_f(f, c - h * xk[i]) + fan_f(f, c + h * xk[i]);
        k += wk[i] * v;
        if (i % 2) g += wg[i / 2] * v;
    }
    *err = fabs((k - g) * h);
    return k * h;
}

static double gk_adapt(const fan *f, double a, double b, double tol, int depth)
{
    double err, v = gk15(f, a, b, &err);
    if (err <= tol || depth <= 0) return v;
    double m = 0.5 * (a + b), t = fmax(0.5 * tol, 1e-17);
    return gk_adapt(f, a, m, t, depth - 1) + gk_adapt(f, m, b, t, depth - 1);
}

/* Light of the round smooth galaxy in the triangle (centre, P, Q), signed positive when
 * P -> Q turns counter-clockwise: in polar coordinates the radial integral is the
 * enclosed-light function, so the cusp at the centre needs no quadrature at all and the
 * angular integrand E(d / cos(theta - phi)) / (2 pi) is smooth. */
static double fan_triangle(const wf_draw_job *jb, const wf_sersic_table *t, double px,
                           double py, double qx, double qy)
{
    double cross = px * qy - py * qx;
    double ex = qx - px, ey = qy - py, len = hypot(ex, ey);
    /* collinear with the centre (a grid line through it): no area, and no direction to the
     * line's foot */
    if (!(fabs(cross) > 1e-12 * hypot(px, py) * hypot(qx, qy))) return 0.0;
    /* the foot of the perpendicular from the centre to the line: R(theta) = d / cos(theta
     * - phi) along the edge */
    double tx = ex / len, ty = ey / len, along = px * tx + py * ty;
    double fx = px - along * tx, fy = py - along * ty;
    fan f = {jb, t, hypot(fx, fy), atan2(fy, fx)};
    double ta = atan2(py, px), tb = atan2(qy, qx);
    double dth = tb - ta; /* the triangle's angle, in (-pi, pi), signed like cross */
    if (dth > M_PI) dth -= 2.0 * M_PI;
    if (dth < -M_PI) dth += 2.0 * M_PI;
    tb = ta + dth;
    /* keep theta - phi in (-pi/2, pi/2) */
    double mid = 0.5 * (ta + tb);
    while (f.phi - mid > M_PI) f.phi -= 2.0 * M_PI;
    while (mid - f.phi > M_PI) f.phi += 2.0 * M_PI;
    return gk_adapt(&f, ta, tb, 1e-12, 12) / (2.0 * M_PI);
}

/* Light of the smooth galaxy in one pixel (corners in arcsec from the centre). */
static double pixel_light(const wf_draw_job *jb, const wf_sersic_table *t, double x0,
                          double y0, double p, int near)
{
    const double(*ai)[2] = jb->shape.ainv;
    if (near) { /* the pixel's corners in round coordinates, counter-clockwise */
        double cx[4] = {x0, x0 + p, x0 + p, x0}, cy[4] = {y0, y0, y0 + p, y0 + p};
        double rx[4], ry[4], sum = 0.0;
        for (int i = 0; i < 4; i++) {
            rx[i] = ai[0][0] * cx[i] + ai[0][1] * cy[i];
            ry[i] = ai[1][0] * cx[i] + ai[1][1] * cy[i];
        }
        for (int i = 0; i < 4; i++)
            sum += fan_triangle(jb, t, rx[i], ry[i], rx[(i + 1) % 4], ry[(i + 1) % 4]);
        return sum;
    }
    /* smooth over the pixel: tensor Gauss-Legendre, with as many nodes as the profile's
     * steepness across the pixel needs */
    double xc = x0 + 0.5 * p, yc = y0 + 0.5 * p;
    double r = hypot(ai[0][0] * xc + ai[0][1] * yc, ai[1][0] * xc + ai[1][1] * yc);
    double slope = 0.0; /* |d ln I / dr| */
    if (jb->fb > 0.0) slope = fmax(slope, 0.25 * t->b * sqrt(sqrt(r / jb->re)) / r);
    if (jb->fd > 0.0) slope = fmax(slope, 1.0 / jb->r0);
    double v = slope * p * jb->shape.smax;
    const double(*g)[2] = v < 0.05 ? gl2 : v < 0.5 ? gl4 : gl8;
    int n = v < 0.05 ? 2 : v < 0.5 ? 4 : 8;
    double sum = 0.0;
    for (int b = 0; b < n; b++)
        for (int a = 0; a < n; a++)
            sum += g[a][1] * g[b][1] * wf_profile_smooth_density(jb, t, xc + 0.5 * p * g[a][0],
                                                                 yc + 0.5 * p * g[b][0]);
    return sum * 0.25 * p * p;
}

/* Without a PSF every pixel is the profile's integral over it, computed directly: exact to
 * ~1e-10 of the flux, no folding, no ringing. Pixels near the centre (where the cusp and
 * the disk's kink are) use the polar fan; the others Gauss-Legendre. */
wf_status wf_profile_draw_nopsf(wf_profile_work *w, const wf_draw_job *jb, double x, double y,
                                wf_stamp *stamp)
{
    const wf_sersic_table *t = w->sersic;
    const double p = w->acc.pixel_scale;
    int nearb = 1 + (int)ceil(jb->shape.smax / jb->shape.smin);
    long ic = lround(x), jc = lround(y);
    for (int yy = 0; yy < stamp->ny; yy++) {
        long py = (long)stamp->y0 + yy;
        double y0 = (py - 0.5 - y) * p;
        for (int xx = 0; xx < stamp->nx; xx++) {
            long px = (long)stamp->x0 + xx;
            int near = labs(px - ic) <= nearb && labs(py - jc) <= nearb;
            double v = jb->fb > 0.0 || jb->fd > 0.0
                           ? pixel_light(jb, t, (px - 0.5 - x) * p, y0, p, near)
                           : 0.0;
            stamp->pix[(size_t)yy * stamp->nx + xx] = v;
        }
    }
    double clipped = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++)
        if (stamp->pix[i] < 0.0) { /* quadrature rounding only */
            clipped -= stamp->pix[i];
            stamp->pix[i] = 0.0;
        }
    for (int j = 0; j < jb->nk; j++) { /* a delta function's pixel integral */
        long px = lround(x + jb->knots[2 * j] / p), py = lround(y + jb->knots[2 * j + 1] / p);
        if (px >= stamp->x0 && px < (long)stamp->x0 + stamp->nx && py >= stamp->y0 &&
            py < (long)stamp->y0 + stamp->ny)
            stamp->pix[(size_t)(py - stamp->y0) * stamp->nx + (size_t)(px - stamp->x0)] +=
                jb->fknot;
    }
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)stamp->nx * stamp->ny; i++) sum += stamp->pix[i];
    stamp->sum = sum;
    stamp->clipped = clipped;
    stamp->fft = 0;
    return WF_OK;
}
