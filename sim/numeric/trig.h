/* Sines and cosines a row at a time, for the drawer's many phasors (knots, phase lines, the
 * PSF image's Fourier sums): libm's sincos costs ~20-35 ns a call and runs one at a time;
 * these run in SIMD lanes (GCC target clones) and agree with it to ~2 ulp of 1.
 *
 * Both reduce to |t| <= pi/4 and sum Taylor's series there to t^17 (sine) and t^18 (cosine),
 * whose truncation is below 1e-19; Horner's rule in double adds about an ulp. */
#ifndef WF_TRIG_H
#define WF_TRIG_H

/* c[i] = cos(2 pi u[i]), s[i] = sin(2 pi u[i]) for u in turns, |u| < 2^50. The whole and
 * quarter turns come off u exactly, so the result does not lose accuracy with |u|. NaN and
 * infinities give NaN. */
void wf_trig_sincos_turns(const double *u, int n, double *c, double *s);

/* c[i] = cos(x[i]), s[i] = sin(x[i]) for x in radians: quarter turns of pi/2 off by
 * Cody and Waite's three-part constant, exact for |x| < 2^20 pi/2 (~1.6e6); beyond it (and
 * for NaN and infinities) libm's. */
void wf_trig_sincos(const double *x, int n, double *c, double *s);

#endif
