/* SN Ia population: see sim/sn/snpop.h and docs/SN_POPULATION.md. */
#include "sim/sn/snpop.h"

#include <math.h>

/* With a valid parameter set at least WF_SNPOP_MIN_ACCEPT of the draws land in range, so this
 * many redraws fail with probability below exp(-1000): reaching it is a bug. */
#define MAX_REDRAWS 1000000

void wf_snpop_default(wf_snpop *p)
{
    *p = (wf_snpop){
        .x1 = {0.973, 1.472, 0.222, -3.0, 2.0},
        .c = {-0.054, 0.043, 0.101, -0.3, 0.5},
        .alpha = 0.14,
        .beta = 3.1,
        .sigma_int = 0.10,
    };
}

/* P(|N(0,1)| σ ≤ d) for d ≥ 0: the chance one side's draw stays within d of the peak. */
static double half_within(double d, double sigma)
{
    return sigma > 0.0 ? erf(d / (sigma * M_SQRT2)) : 1.0;
}

static wf_status check_agauss(const wf_snpop_agauss *g, const char *name)
{
    const double v[5] = {g->peak, g->sigma_minus, g->sigma_plus, g->lo, g->hi};
    static const char *const field[5] = {"peak", "sigma_minus", "sigma_plus", "lo", "hi"};
    for (int i = 0; i < 5; i++)
        if (!isfinite(v[i]))
            return wf_error(WF_ERR_RANGE, "SN population: %s.%s = %g is not finite", name,
                            field[i], v[i]);
    if (g->sigma_minus < 0.0)
        return wf_error(WF_ERR_RANGE, "SN population: %s.sigma_minus = %g is negative", name,
                        g->sigma_minus);
    if (g->sigma_plus < 0.0)
        return wf_error(WF_ERR_RANGE, "SN population: %s.sigma_plus = %g is negative", name,
                        g->sigma_plus);
    if (!(g->sigma_minus + g->sigma_plus > 0.0))
        return wf_error(WF_ERR_RANGE,
                        "SN population: %s.sigma_minus and %s.sigma_plus are both zero", name,
                        name);
    if (!(g->lo < g->hi))
        return wf_error(WF_ERR_RANGE, "SN population: %s.lo = %g must be below %s.hi = %g", name,
                        g->lo, name, g->hi);
    if (!(g->peak >= g->lo && g->peak <= g->hi))
        return wf_error(WF_ERR_RANGE, "SN population: %s.peak = %g is outside [%s.lo, %s.hi] = "
                        "[%g, %g]", name, g->peak, name, name, g->lo, g->hi);
    double s = g->sigma_minus + g->sigma_plus;
    double accept = g->sigma_minus / s * half_within(g->peak - g->lo, g->sigma_minus) +
                    g->sigma_plus / s * half_within(g->hi - g->peak, g->sigma_plus);
    if (accept < WF_SNPOP_MIN_ACCEPT)
        return wf_error(WF_ERR_RANGE,
                        "SN population: %s: [%s.lo, %s.hi] = [%g, %g] holds only %.3g of the "
                        "distribution (< %g): widen the range",
                        name, name, name, g->lo, g->hi, accept, WF_SNPOP_MIN_ACCEPT);
    return WF_OK;
}

wf_status wf_snpop_validate(const wf_snpop *p)
{
    if (!p) return wf_error(WF_ERR_INPUT, "SN population: no parameters given");
    wf_status st = check_agauss(&p->x1, "x1");
    if (!st) st = check_agauss(&p->c, "c");
    if (st) return st;
    if (!isfinite(p->alpha))
        return wf_error(WF_ERR_RANGE, "SN population: alpha = %g is not finite", p->alpha);
    if (!isfinite(p->beta))
        return wf_error(WF_ERR_RANGE, "SN population: beta = %g is not finite", p->beta);
    if (!(p->sigma_int >= 0.0 && isfinite(p->sigma_int)))
        return wf_error(WF_ERR_RANGE, "SN population: sigma_int = %g must be finite and >= 0",
                        p->sigma_int);
    return WF_OK;
}

wf_status wf_snpop_agauss_draw(const wf_snpop_agauss *g, wf_rng *rng, double *x)
{
    double pminus = g->sigma_minus / (g->sigma_minus + g->sigma_plus);
    for (int k = 0; k < MAX_REDRAWS; k++) {
        int minus = wf_rng_uniform53(rng) < pminus;
        double n = fabs(wf_rng_gauss(rng));
        double v = minus ? g->peak - n * g->sigma_minus : g->peak + n * g->sigma_plus;
        if (v >= g->lo && v <= g->hi) {
            *x = v;
            return WF_OK;
        }
    }
    return wf_error(WF_ERR_INTERNAL,
                    "SN population: %d redraws without a value in [%g, %g] (peak %g)",
                    MAX_REDRAWS, g->lo, g->hi, g->peak);
}

wf_status wf_snpop_x0(const wf_snpop *p, double mu, double x1, double c, double delta,
                      double *x0)
{
    if (!p) return wf_error(WF_ERR_INPUT, "SN population: no parameters given");
    if (!(isfinite(mu) && isfinite(x1) && isfinite(c) && isfinite(delta)))
        return wf_error(WF_ERR_RANGE,
                        "SN population: x0 needs finite mu, x1, c, delta (got %g, %g, %g, %g)",
                        mu, x1, c, delta);
    *x0 = 1.0 / (1e-12 * pow(10.0, 0.4 * (mu - p->alpha * x1 + p->beta * c + delta)));
    return WF_OK;
}

wf_status wf_snpop_draw(const wf_snpop *p, wf_rng *rng, double mu, wf_sn_params *out)
{
    wf_status st = wf_snpop_validate(p);
    if (st) return st;
    if (!isfinite(mu))
        return wf_error(WF_ERR_RANGE, "SN population: distance modulus mu = %g is not finite",
                        mu);
    wf_sn_params s;
    st = wf_snpop_agauss_draw(&p->x1, rng, &s.x1);
    if (!st) st = wf_snpop_agauss_draw(&p->c, rng, &s.c);
    if (st) return st;
    s.delta = p->sigma_int * wf_rng_gauss(rng);
    s.mu = mu;
    st = wf_snpop_x0(p, mu, s.x1, s.c, s.delta, &s.x0);
    if (st) return st;
    *out = s;
    return WF_OK;
}
