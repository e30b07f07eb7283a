"""STScI's drizzle on the inputs of a wfisim coadd, compared with it (tests/test_coadd.c).

usage: drizzle_reference.py COADD.fits INPUT.fits...

Each input is drizzled with drizzle.cdrizzle.tdriz (python3-drizzle, the C core of
STScI's drizzle): square kernel, the coadd's PIXFRAC, one weight per input (wfisim's
convention, analysis/coadd.h: 1/median(ERR)^2 over the good pixels of 64 rows spread over
the image, rows step/2, step/2 + step, ... with step = ny // 64) with DQ-flagged pixels 0,
units cps, and the pixmap (input pixel centre -> output pixel, 0-based) from
astropy's WCS of each header. scale is the output/input pixel-scale ratio.

Debian bookworm's python3-drizzle 1.13.4 carries C core 1.12, which interpolates the
pixmap along the wrong axis for the square kernel's corners (STScI drizzle #82/#83,
JP-2702: a sub-pixel shift when input and output axes are rotated): the test therefore
compares inputs whose axes are aligned with the output's (different scale, sub-pixel
dithers), where that bug has no effect. Prints
    max_rel_sci X max_rel_wht Y
the largest differences over the pixels compared, relative to the largest |SCI| and WHT.
"""
import sys

import numpy as np
from astropy.io import fits
from astropy.wcs import WCS
from drizzle import cdrizzle


def main():
    out = fits.open(sys.argv[1])
    owcs = WCS(out['SCI'].header)
    sci_w = out['SCI'].data.astype(np.float64)
    wht_w = out['WHT'].data.astype(np.float64)
    pixfrac = float(out[0].header['PIXFRAC'])
    mask = int(out[0].header['DQMASK'])
    oscale = np.sqrt(abs(np.linalg.det(owcs.pixel_scale_matrix)))
    shape = sci_w.shape
    osci = np.zeros(shape, np.float32)
    owht = np.zeros(shape, np.float32)
    octx = np.zeros(shape, np.int32)
    for k, path in enumerate(sys.argv[2:]):
        h = fits.open(path)
        sci = h['SCI'].data.astype(np.float32)
        err = h['ERR'].data.astype(np.float64)
        dq = h['DQ'].data.astype(np.int64)
        iwcs = WCS(h['SCI'].header)
        iscale = np.sqrt(abs(np.linalg.det(iwcs.pixel_scale_matrix)))
        step = max(1, sci.shape[0] // 64)
        rows = np.arange(step // 2, sci.shape[0], step)
        e = err[rows][((dq[rows] & mask) == 0) & np.isfinite(err[rows]) & (err[rows] > 0)]
        m = float(np.median(e))
        w = np.where((dq & mask) == 0, 1.0 / (m * m), 0.0).astype(np.float32)
        # Debian's drizzle (C core 1.12) leaves out input pixels at the image's edges (the
        # last row and column, its scan-line bugs: STScI drizzle #63, #89, #104): pad all
        # round with pixels of weight 0 so that only the padding is left out
        P = 2
        ny, nx = sci.shape[0] + 2 * P, sci.shape[1] + 2 * P
        sci = np.pad(sci, P)
        w = np.pad(w, P)
        y, x = np.indices((ny, nx), dtype=np.float64) - P
        ra, dec = iwcs.all_pix2world(x, y, 0)
        ox, oy = owcs.all_world2pix(ra, dec, 0)
        pixmap = np.dstack([ox, oy])
        cdrizzle.tdriz(sci, w, pixmap, osci, owht, octx, uniqid=k + 1, xmin=0, xmax=nx - 1, ymin=0,
                       ymax=ny - 1, scale=oscale / iscale, pixfrac=pixfrac, kernel='square',
                       in_units='cps', expscale=1.0, wtscale=1.0, fillstr='0')
    good = (owht > 0) | (wht_w > 0)
    print("total weight: wfisim %.6f, drizzle %.6f" % (wht_w.sum(), owht.sum()))
    dsci = np.max(np.abs(osci[good] - sci_w[good])) / np.max(np.abs(sci_w[good]))
    dwht = np.max(np.abs(owht[good] - wht_w[good])) / np.max(wht_w[good])
    print("pixels with weight: wfisim %d, drizzle %d" % (np.sum(wht_w > 0), np.sum(owht > 0)))
    print("max_rel_sci %.3e max_rel_wht %.3e" % (dsci, dwht))


if __name__ == '__main__':
    main()
