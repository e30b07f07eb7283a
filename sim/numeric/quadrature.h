/* Gauss–Legendre quadrature: the project's rules and one composite integrator.
 *
 * An n-point rule integrates polynomials of degree ≤ 2n − 1 exactly on [−1, 1]. Each rule
 * is a fixed table (sim/numeric/quadrature.c gives where its digits come from): nodes ascending and
 * symmetric bit for bit (x[n−1−i] = −x[i], w[n−1−i] = w[i]), so that a caller may walk
 * them in either direction or in ± pairs and keep the sums it had before the tables were
 * shared. */
#ifndef WF_QUADRATURE_H
#define WF_QUADRATURE_H

typedef struct wf_quad_rule {
    int n;
    const double *x; /* nodes on [−1, 1], ascending */
    const double *w; /* weights, summing to 2 */
} wf_quad_rule;

extern const wf_quad_rule wf_quad_gl3;  /* SALT light-curve integrals (sim/sn/salt.c) */
extern const wf_quad_rule wf_quad_gl14; /* de Vaucouleurs Hankel transform (sim/draw/profile_sersic.c) */
extern const wf_quad_rule wf_quad_gl16; /* distances and SN rates (sim/sn/cosmology.c, sim/sn/snrate.c) */

/* ∫_a^b f(x) dx by `rule` on `panels` equal panels (fewer than 1 counts as 1; a > b gives
 * the negative). Each panel sums its ± node pairs from the centre outwards, after the
 * centre node of an odd rule. */
double wf_quad_gl(const wf_quad_rule *rule, double (*f)(double x, void *ctx), void *ctx,
                  double a, double b, int panels);

#endif
