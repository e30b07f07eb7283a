/* `wfisim psf ...`: one PSF image, as galsim.roman.getPSF(...).drawImage gives GalSim users.
 *
 *   wfisim psf --filter F --sca N [--pupil-bin B] [--oversample K] [--wavelength NM | --sed flat
 *              [--nlambda N]] [--size PIX] [--x X --y Y] [--jitter ARCSEC] [--diffusion PX]
 *              [--pixel on|off] [--data DIR|none] --out FILE
 *
 * Writes FILE (through FILE.tmp) with one float64 image normalised to unit flux before
 * truncation to the stamp, the PSF centred on the image's true centre (GalSim's convention),
 * sampled every 0.11/K arcsec, with the pixel response when K = 1 (or --pixel on), and every
 * setting in the header. Without --wavelength the band's effective wavelength comes from
 * sim/optics/bandpass.h (the data's effective-area curve, else the built-in top-hat); --sed flat is
 * chromatic: N wavelengths across the band weighted by throughput / λ (photons from a source
 * flat in f_ν). Masks and aberrations come from DIR/roman/ (--data, else $WFISIM_DATA);
 * "--data none" or neither set: the analytic pupil without aberrations (docs/OPTICS.md). */
#ifndef WF_PSFCMD_H
#define WF_PSFCMD_H

/* argv holds the options after "psf" (a leading "psf" is skipped if present). Returns the
 * process exit status: 0 done, 1 failure (I/O, memory), 2 bad usage or input. */
int wf_cmd_psf(int argc, char **argv);

#endif
