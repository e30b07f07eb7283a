/* Flat ΛCDM distances: see sim/sn/cosmology.h and docs/SN_POPULATION.md. */
#include "sim/sn/cosmology.h"

#include <math.h>

#include "sim/numeric/quadrature.h"

/* Widest panel in u = (1+z)^(-1/2); see the header for why 0.1 is enough. */
#define PANEL_U 0.1

static wf_status check_z(const wf_cosmo *c, double z, const char *what)
{
    if (!c) return wf_error(WF_ERR_INPUT, "cosmology: %s: no cosmology given", what);
    if (!(z >= 0.0 && z <= WF_COSMO_ZMAX))
        return wf_error(WF_ERR_RANGE,
                        "cosmology: %s: redshift %g is outside [0, %g] (radiation is neglected "
                        "in this model)",
                        what, z, WF_COSMO_ZMAX);
    return WF_OK;
}

wf_status wf_cosmo_init(wf_cosmo *c, double h0, double om)
{
    if (!c) return wf_error(WF_ERR_INPUT, "cosmology: no struct to initialise");
    if (!(h0 >= 1.0 && h0 <= 1000.0))
        return wf_error(WF_ERR_RANGE,
                        "cosmology: H0 = %g km/s/Mpc is outside [1, 1000] (give H0, not h)", h0);
    if (!(om >= 0.0 && om <= 1.0))
        return wf_error(WF_ERR_RANGE,
                        "cosmology: Omega_m = %g is outside [0, 1] (flat: Omega_Lambda = "
                        "1 - Omega_m must be >= 0)",
                        om);
    c->h0 = h0;
    c->om = om;
    c->ol = 1.0 - om;
    c->dh = WF_COSMO_C_KMS / h0;
    return WF_OK;
}

static double efunc(const wf_cosmo *c, double z)
{
    double a = 1.0 + z;
    return sqrt(c->om * a * a * a + c->ol);
}

wf_status wf_cosmo_hubble(const wf_cosmo *c, double z, double *km_s_mpc)
{
    wf_status st = check_z(c, z, "H(z)");
    if (st) return st;
    *km_s_mpc = c->h0 * efunc(c, z);
    return WF_OK;
}

/* In v = u - 1 so that the panel ends near v = 0 (tiny z) keep their relative precision. */
static double dv_integrand(double v, void *ctx)
{
    const wf_cosmo *c = ctx;
    double u = 1.0 + v, u2 = u * u;
    return 2.0 / sqrt(c->om + c->ol * u2 * u2 * u2);
}

/* ∫0^z dz'/E in units of c/H0, for a checked z. */
static double dc_over_dh(const wf_cosmo *c, double z)
{
    if (z == 0.0) return 0.0;
    double s = sqrt(1.0 + z);
    /* 1 - 1/s written without cancellation so tiny z keeps its relative accuracy */
    double width = z / (s * (s + 1.0));
    int panels = (int)ceil(width / PANEL_U);
    return wf_quad_gl(&wf_quad_gl16, dv_integrand, (void *)c, -width, 0.0, panels);
}

wf_status wf_cosmo_comoving_distance(const wf_cosmo *c, double z, double *mpc)
{
    wf_status st = check_z(c, z, "comoving distance");
    if (st) return st;
    *mpc = c->dh * dc_over_dh(c, z);
    return WF_OK;
}

wf_status wf_cosmo_luminosity_distance(const wf_cosmo *c, double z, double *mpc)
{
    wf_status st = check_z(c, z, "luminosity distance");
    if (st) return st;
    *mpc = (1.0 + z) * c->dh * dc_over_dh(c, z);
    return WF_OK;
}

wf_status wf_cosmo_distance_modulus(const wf_cosmo *c, double z, double *mu)
{
    wf_status st = check_z(c, z, "distance modulus");
    if (st) return st;
    if (z == 0.0)
        return wf_error(WF_ERR_RANGE, "cosmology: distance modulus: redshift must be > 0");
    *mu = 5.0 * log10((1.0 + z) * c->dh * dc_over_dh(c, z)) + 25.0;
    return WF_OK;
}

wf_status wf_cosmo_dvdz(const wf_cosmo *c, double z, double *mpc3_per_sr)
{
    wf_status st = check_z(c, z, "volume element");
    if (st) return st;
    double dc = c->dh * dc_over_dh(c, z);
    *mpc3_per_sr = c->dh * dc * dc / efunc(c, z);
    return WF_OK;
}
