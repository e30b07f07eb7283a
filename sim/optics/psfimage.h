/* The PSF as the profile drawer takes it: an oversampled image of the optical PSF (jitter and
 * charge diffusion included if wanted) WITHOUT the pixel response, which the drawer applies
 * itself; this is what GalSim's drawImage(method='no_pixel') produces. Kept apart from
 * sim/optics/psf.h so that the PSF builder and the profile drawer depend on this one struct only.
 *
 * Conventions (those of GalSim's drawImage on an n x n image with no offset):
 *  - pix[j * n + i] is the PSF's surface brightness at the point
 *      x = (i - (n - 1) / 2) * scale_arcsec,  y = (j - (n - 1) / 2) * scale_arcsec
 *    times scale_arcsec^2 (a sample, not an integral), so that the sum of pix is the flux
 *    the image holds;
 *  - x runs along SCA columns, y along SCA rows (the same axes as the stamp);
 *  - the PSF centre is the array's true centre, between samples when n is even;
 *  - the image is used as given: its sum is the fraction of the PSF's flux it holds (a
 *    truncated image, like GalSim's 128 x 128 OVER4 with sum 0.978, loses its wings; pass a
 *    normalised image to draw every object's full flux within the stamp).
 * scale_arcsec must resolve the optics: below lambda / (2 D) (0.046" at 1.06 um); an integer
 * fraction of the 0.11" pixel (0.11 / 2, / 4, ...) takes the fast exact path. */
#ifndef WF_PSFIMAGE_H
#define WF_PSFIMAGE_H

typedef struct wf_psf_image {
    int n;               /* n x n samples, n >= 2 */
    double scale_arcsec; /* sample spacing */
    const double *pix;   /* row-major, n * n, owned by the caller */
    double band_limit;   /* rad/arcsec beyond which the PSF has no power: 2 pi D / lambda
                            (lambda the shortest wavelength drawn; 67.85 for Y106 at 1.0595 um
                            and D = 2.36 m). 0: unknown, the image's transform is used out to
                            where it falls below 1e-7, which keeps any resampling artifacts
                            the image holds above the optical cut-off (GalSim's OVER4 images
                            hold ~3% there) and costs up to 5x the time per draw. */
} wf_psf_image;

#endif
