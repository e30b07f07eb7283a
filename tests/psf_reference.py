#!/usr/bin/python3
"""An independent Roman PSF, for tests/test_psf.c: brute force, GalSim's conventions.

usage: psf_reference.py DATA_DIR FILTER SCA PUPIL_BIN LAM_NM N PIXEL_ARCSEC [NODES]

Prints the N x N image of the achromatic PSF of FILTER on SCA (at the SCA centre) at LAM_NM,
drawn as GalSim's drawImage draws a PSF with the pixel response: each value is the flux (unit
total flux) that falls on a PIXEL_ARCSEC square pixel, the PSF centred on the image's true
centre ((N-1)/2 in 0-based pixel units, a pixel corner for even N). One line per row, row 0
(y) first, '%.15e' values; a first line '# peak <max> sum <sum>'.

It shares no code and no method with sim/optics/psf.c. What it follows is GalSim's documented
conventions for galsim.roman.getPSF (OpticalPSF with an Aperture built from the pupil image):
  - pupil: DATA_DIR/roman/RST_WIM_Filter_{skinny|F184}_SCA_<n>.fits.gz (F184 for F184 and
    K213), its header's PIXELSCL (m per sample); binned as galsim.Image.bin does (sums of
    PUPIL_BIN x PUPIL_BIN blocks from the array's origin) and illuminated where the sum > 0
    (galsim.Aperture); sample (i, j) of the binned array at u = (i - n/2) dx, v = (j - n/2) dx
    (the Aperture's fftfreq grid, whatever the zero padding);
  - aberrations: DATA_DIR/roman/Roman_Cycle-9_WFI_zim_zernikes_082623_NN.txt, columns 6-27 Noll
    Z1..Z22 in waves at 1293 nm; at the SCA centre, bilinear between the four corner points
    (pixel x = x_mm/0.01 + 2044, y = 2044 - y_mm/0.01); Z1-Z3 dropped; scaled by 1293/LAM_NM;
    circular Noll Zernikes (galsim.zernike) on the circle of radius diam/2 = 1.18 m, evaluated
    here from the radial formula in polar coordinates;
  - PSF: |E(theta)|^2 with E the pupil field's Fourier integral, E(theta) = sum P exp(2 pi i W)
    exp(+2 pi i theta.u / lambda) (this sign gives GalSim's orientation of the Roman images:
    with the other one the coma of the SCA 1 images points the other way), normalised by
    Parseval to unit flux over one period lambda/dx of the sampled pupil.

Method: E is evaluated directly (a matrix Fourier transform, no FFT grid, no interpolation) at
the NODES x NODES Gauss-Legendre nodes of every pixel (default 12), and each pixel is the
Gauss-Legendre quadrature of |E|^2 over it. |E|^2 is a trigonometric polynomial with at most
~2 cycles across a pixel (R062), so the quadrature converges exponentially: 12 and 16 nodes
agree to 1e-15 of the peak (8 nodes: 2e-8 at R062). Needs numpy and astropy; exits 3 with
'NO_NUMPY <reason>' when either cannot be imported.
"""
import math
import os
import sys

ARCSEC_PER_RAD = 180.0 / math.pi * 3600.0
ZEMAX_NM = 1293.0
DIAM = 2.36
LONGWAVE = ("F184", "K213")


def noll_to_nm(j):
    """Noll index -> (n, m), m signed: m > 0 for cos (even j), m < 0 for sin (odd j)."""
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    # the |m| values of row n in Noll's order, two per |m| > 0
    ms = []
    for mm in range(n % 2, n + 1, 2):
        ms += [mm] if mm == 0 else [mm, mm]
    mabs = ms[j - n * (n + 1) // 2 - 1]
    if mabs == 0:
        return n, 0
    return n, (mabs if j % 2 == 0 else -mabs)


def zernike(j, rho, phi):
    import numpy as np
    n, m = noll_to_nm(j)
    mabs = abs(m)
    radial = np.zeros_like(rho)
    for s in range((n - mabs) // 2 + 1):
        c = ((-1) ** s * math.factorial(n - s) /
             (math.factorial(s) * math.factorial((n + mabs) // 2 - s) *
              math.factorial((n - mabs) // 2 - s)))
        radial = radial + c * rho ** (n - 2 * s)
    if m == 0:
        return math.sqrt(n + 1.0) * radial
    ang = np.cos(mabs * phi) if m > 0 else np.sin(mabs * phi)
    return math.sqrt(2.0 * (n + 1.0)) * radial * ang


def corner_aberrations(path):
    """Noll Z1..Z22 (index 1..22 of a 23-array) at the SCA centre, bilinear in the corners."""
    import numpy as np
    rows = [list(map(float, ln.split())) for ln in open(path) if ln.strip() and ln.lstrip()[0] != '#']
    if len(rows) != 5 or any(len(r) != 27 for r in rows):
        raise ValueError("%s: want 5 lines of 27 columns" % path)
    d = np.array(rows)
    x = d[:, 1] / 0.01 + 2044.0
    y = 2044.0 - d[:, 2] / 0.01
    corners = np.argsort((x - 2044.0) ** 2 + (y - 2044.0) ** 2)[1:]
    fx = (2044.0 - x[corners].min()) / (x[corners].max() - x[corners].min())
    fy = (2044.0 - y[corners].min()) / (y[corners].max() - y[corners].min())
    ab = np.zeros(23)
    for k in corners:
        wx = fx if x[k] > 2044.0 else 1.0 - fx
        wy = fy if y[k] > 2044.0 else 1.0 - fy
        ab[1:] += wx * wy * d[k, 5:]
    ab[:4] = 0.0
    return ab


def main():
    if len(sys.argv) not in (8, 9):
        sys.stderr.write(__doc__)
        return 2
    try:
        import numpy as np
        from astropy.io import fits
    except Exception as e:  # noqa: BLE001 - any import failure means: skip
        print("NO_NUMPY %s" % e)
        return 3
    data, band, sca, pbin = sys.argv[1], sys.argv[2].upper(), int(sys.argv[3]), int(sys.argv[4])
    lam_nm, npix, pix = float(sys.argv[5]), int(sys.argv[6]), float(sys.argv[7])
    nodes = int(sys.argv[8]) if len(sys.argv) == 9 else 12
    roman = os.path.join(data, "roman")

    mask_name = "RST_WIM_Filter_%s_SCA_%d.fits.gz" % ("F184" if band in LONGWAVE else "skinny", sca)
    with fits.open(os.path.join(roman, mask_name)) as hdul:
        raw = np.asarray(hdul[0].data, dtype=np.float64)
        dx = float(hdul[0].header["PIXELSCL"]) * pbin
    n0 = raw.shape[0]
    nb = n0 // pbin
    binned = raw.reshape(nb, pbin, nb, pbin).sum(axis=(1, 3))  # [row = v][column = u]
    open_ = binned > 0

    ab = corner_aberrations(os.path.join(roman, "Roman_Cycle-9_WFI_zim_zernikes_082623_%02d.txt" % sca))
    ab *= ZEMAX_NM / lam_nm  # waves at lam

    # the open samples' bounding box: only those enter the Fourier integral
    rows = np.nonzero(open_.any(axis=1))[0]
    cols = np.nonzero(open_.any(axis=0))[0]
    j0, j1, i0, i1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    u = (np.arange(i0, i1) - nb / 2) * dx
    v = (np.arange(j0, j1) - nb / 2) * dx
    uu, vv = np.meshgrid(u, v)
    rho = np.hypot(uu, vv) / (DIAM / 2)
    phi = np.arctan2(vv, uu)
    waves = np.zeros_like(rho)
    for j in range(4, 23):
        if ab[j] != 0.0:
            waves += ab[j] * zernike(j, rho, phi)
    field = np.where(open_[j0:j1, i0:i1], np.exp(2j * np.pi * waves), 0.0)

    # Gauss-Legendre nodes of every pixel, in arcsec from the PSF centre
    t, w = np.polynomial.legendre.leggauss(nodes)
    centres = (np.arange(npix) - 0.5 * (npix - 1)) * pix
    theta = (centres[:, None] + 0.5 * pix * t[None, :]).ravel()
    lam_m = lam_nm * 1e-9
    ax = np.exp(2j * np.pi * np.outer(theta / ARCSEC_PER_RAD, u) / lam_m)  # [theta_x][u]
    ay = np.exp(2j * np.pi * np.outer(theta / ARCSEC_PER_RAD, v) / lam_m)  # [theta_y][v]
    e = ay @ field @ ax.T  # [theta_y][theta_x]
    inten = (e * e.conj()).real
    # unit flux over one period T = lambda/dx (arcsec): Parseval gives int |E|^2 = T^2 sum|P|^2
    period = lam_m / dx * ARCSEC_PER_RAD
    inten /= period ** 2 * np.count_nonzero(open_)
    # each pixel: the mean over its nodes (weights sum to 2 per axis) times its area
    img = np.einsum("anbm,nm->ab", inten.reshape(npix, nodes, npix, nodes), np.outer(w, w) / 4.0)
    img *= pix * pix
    print("# peak %.15e sum %.15e" % (img.max(), img.sum()))
    for row in img:
        print(" ".join("%.15e" % val for val in row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
