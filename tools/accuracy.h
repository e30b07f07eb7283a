/* `wfisim accuracy psf|galaxy|scene|detector|all`: error against CPU time for every accuracy
 * knob of the scene rendering (issue 3), each knob swept with the others at their defaults
 * and compared with the sweep's highest-fidelity setting (docs/ACCURACY.md has the results).
 *
 *   wfisim accuracy psf|galaxy|scene|detector|all [--filter F] [--sca N] [--out DIR]
 *                   [--data DIR|none] [--quick]
 *
 *  - psf: pupil_bin, PSF image oversampling, PSF image size, achromatic vs chromatic (flat
 *    f_nu SED), the scene's star against the exact pixel-integrated PSF; measured on a star
 *    drawn as the scene draws it, at 0.11" with the pixel response;
 *  - galaxy: flux_fraction, folding_threshold, kvalue_accuracy, knots, for small, medium,
 *    large, bulge- and disk-dominated galaxies;
 *  - scene: a corner of the SCA with a synthetic field: pupil_bin, PSF oversampling, PSF
 *    image size and flux_fraction on the noise-free rates, and the ramp sampling (per-read,
 *    direct, moments, single) through readout, assembly and ramp fit;
 *  - detector: what leaving an effect out does to a star's photometry (persistence: a faint
 *    star on the pixels of a saturating one that ended 56-3600 s before).
 *
 * Writes DIR/accuracy_<kind>.csv (one row per setting), DIR/accuracy.md (the tables) and
 * PNG plots of error against CPU time, each through a temporary file and a rename. --quick
 * is a reduced sweep of a few seconds. Masks and Zernikes from DIR/roman (--data, else
 * $WFISIM_DATA; "none": the analytic pupil). */
#ifndef WF_ACCURACY_H
#define WF_ACCURACY_H

/* argv[0] is "accuracy". Returns the process exit status: 0 done, 1 failure (I/O, memory),
 * 2 bad usage (the message on stderr names the option). */
int wf_cmd_accuracy(int argc, char **argv);

#endif
