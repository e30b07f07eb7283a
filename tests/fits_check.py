#!/usr/bin/python3
"""Checks a wfisim FITS product with astropy, independently of cfitsio.

    fits_check.py FILE [--shape ROWSxCOLS] [--nres N] [--cosmic N] [--compressed]

HDU order and names (PRIMARY, SCI, ERR, DQ, then RESULTANTS in ramp mode and COSMICRAYS
when present), image types and shapes, and CHECKSUM/DATASUM of every HDU (a tile-compressed
image's are those of its binary table, checked as such). --compressed: the image HDUs must
be tile-compressed. Exits 0 when all hold, 1 with a message per failure otherwise.
"""
import argparse
import sys
import warnings

import numpy as np
from astropy.io import fits


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("--shape", help="ROWSxCOLS of the images")
    ap.add_argument("--nres", type=int, help="resultants (ramp mode)")
    ap.add_argument("--cosmic", type=int, help="rows expected in COSMICRAYS")
    ap.add_argument("--compressed", action="store_true", help="image HDUs tile-compressed")
    args = ap.parse_args()
    bad = []

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            hdul = fits.open(args.file, checksum=True, memmap=False)
        except Exception as exc:  # any failure to read is a failed check
            print(f"{args.file}: cannot open: {exc}")
            return 1
        with hdul:
            hdul.verify("exception")
            names = [h.name for h in hdul]
            for h in hdul:
                h.data  # force reading so data checksums are exercised
                compressed = isinstance(h, fits.CompImageHDU)
                if args.compressed and h.name in ("SCI", "ERR", "DQ", "RESULTANTS") and not compressed:
                    bad.append(f"{h.name}: not tile-compressed")
                if "CHECKSUM" not in h.header or "DATASUM" not in h.header:
                    bad.append(f"{h.name}: no CHECKSUM/DATASUM")
                elif not compressed and (h.verify_checksum() != 1 or h.verify_datasum() != 1):
                    bad.append(f"{h.name}: checksum does not verify")
            want = ["PRIMARY", "SCI", "ERR", "DQ"]
            if "RESULTANTS" in names or args.nres:
                want.append("RESULTANTS")
            if "COSMICRAYS" in names or args.cosmic is not None:
                want.append("COSMICRAYS")
            if names != want:
                bad.append(f"HDUs {names}, expected {want}")
            else:
                shape = tuple(hdul["SCI"].data.shape)
                if args.shape:
                    rows, cols = (int(v) for v in args.shape.lower().split("x"))
                    if shape != (rows, cols):
                        bad.append(f"SCI shape {shape}, expected {(rows, cols)}")
                for name, kind in (("SCI", np.float32), ("ERR", np.float32), ("DQ", np.uint32)):
                    d = hdul[name].data
                    if d.shape != shape:
                        bad.append(f"{name} shape {d.shape}, SCI {shape}")
                    if d.dtype.type is not kind:
                        bad.append(f"{name} dtype {d.dtype}, expected {np.dtype(kind)}")
                if not np.all(np.isfinite(hdul["SCI"].data)):
                    bad.append("SCI holds non-finite values")
                if "RESULTANTS" in names:
                    d = hdul["RESULTANTS"].data
                    if d.dtype.type is not np.uint16:
                        bad.append(f"RESULTANTS dtype {d.dtype}, expected uint16")
                    if d.shape[1:] != shape or (args.nres and d.shape[0] != args.nres):
                        bad.append(f"RESULTANTS shape {d.shape}")
                if "COSMICRAYS" in names:
                    t = hdul["COSMICRAYS"].data
                    cols = list(t.columns.names)
                    if cols != ["X0", "Y0", "X1", "Y1", "ELECTRONS", "READ", "ID"]:
                        bad.append(f"COSMICRAYS columns {cols}")
                    if args.cosmic is not None and len(t) != args.cosmic:
                        bad.append(f"COSMICRAYS has {len(t)} rows, expected {args.cosmic}")
                    if len(t) > 1 and np.any(np.diff(t["ID"].astype(np.int64)) <= 0):
                        bad.append("COSMICRAYS not sorted by ID")
    try:  # every HDU as stored: a compressed image as its table, checksums and all
        with fits.open(args.file, disable_image_compression=True, memmap=False) as raw:
            for h in raw:
                if isinstance(h, fits.BinTableHDU) and "ZIMAGE" in h.header and (
                        h.verify_checksum() != 1 or h.verify_datasum() != 1):
                    bad.append(f"{h.name}: checksum of the compressed table does not verify")
    except Exception as exc:
        bad.append(f"cannot read the HDUs as stored: {exc}")
    for w in caught:
        if "checksum" in str(w.message).lower() or "datasum" in str(w.message).lower():
            bad.append(f"astropy: {w.message}")
    for b in bad:
        print(f"{args.file}: {b}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
