#!/usr/bin/python3
"""Error the quantization of SCI puts on aperture photometry (bench/products.sh).

    quant_photometry.py PLAIN.fits TRUTH.fits Q=COMPRESSED.fits ...

For every galaxy and star of the truth table whose aperture lies on the SCA: the flux in a
circular aperture (radius 3 pixels) on the plain and on each compressed SCI, and the
aperture's photometric noise from ERR. Prints a Markdown table: per quantize level, the rms
and mean of the flux difference over the objects in units of their noise, and the rms the
steps cfitsio chose predict (each pixel's step / sqrt 12, added in quadrature).
"""
import sys

import numpy as np
from astropy.io import fits

R = 3.0


def main():
    plain, truth, pairs = sys.argv[1], sys.argv[2], [a.split("=", 1) for a in sys.argv[3:]]
    with fits.open(plain) as h:
        sci0 = h["SCI"].data.astype(np.float64)
        err = h["ERR"].data.astype(np.float64)
    ny, nx = sci0.shape
    xs, ys = [], []
    with fits.open(truth) as t:
        for name in ("GALAXIES", "STARS"):
            if name in t:
                xs.append(np.asarray(t[name].data["X"], float))
                ys.append(np.asarray(t[name].data["Y"], float))
    x, y = np.concatenate(xs), np.concatenate(ys)
    keep = (x > R + 1) & (x < nx - R - 2) & (y > R + 1) & (y < ny - R - 2)
    x, y = x[keep], y[keep]
    r = int(np.ceil(R))
    oy, ox = np.mgrid[-r:r + 1, -r:r + 1]
    print("| q | objects | rms error / noise | mean error / noise | predicted rms / noise | median noise e-/s |")
    print("|---|---|---|---|---|---|")
    for q, path in pairs:
        with fits.open(path) as h:
            sci = h["SCI"].data.astype(np.float64)
        with fits.open(path, disable_image_compression=True) as h:
            step = np.asarray(h["SCI"].data["ZSCALE"], float)  # one tile per row
        d, noise, pred = [], [], []
        for cx, cy in zip(x, y):
            ix, iy = int(round(cx)), int(round(cy))
            m = (ox + ix - cx) ** 2 + (oy + iy - cy) ** 2 <= R * R
            yy, xx = (oy + iy)[m], (ox + ix)[m]
            d.append(np.sum(sci[yy, xx] - sci0[yy, xx]))
            noise.append(np.sqrt(np.sum(err[yy, xx] ** 2)))
            pred.append(np.sqrt(np.sum(step[yy] ** 2 / 12)))
        d, noise, pred = np.array(d), np.array(noise), np.array(pred)
        z = d / noise
        print(f"| {q} | {len(z)} | {np.sqrt(np.mean(z ** 2)):.4f} | {np.mean(z):+.5f} | "
              f"{np.sqrt(np.mean((pred / noise) ** 2)):.4f} | {np.median(noise):.3g} |")


if __name__ == "__main__":
    main()
