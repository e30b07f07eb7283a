#!/usr/bin/python3
"""sncosmo's synthetic photometry of a SALT2/SALT3 model, for tests/test_salt.c.

usage: salt_sncosmo.py MODEL_DIR JOBS_FILE

MODEL_DIR holds salt2_* or salt3_* model files. Each line of JOBS_FILE is
    BAND_FILE z x0 x1 c t0 mjd
where BAND_FILE has two columns, wavelength [nm] and throughput (photon counting).
For each job one line is printed: the AB magnitude from sncosmo's Model.bandmag,
"out" when sncosmo refuses the band (outside the model's wavelength range), or
"zero" when the band flux is not positive. Lines starting with '#' are comments.

The Source is built only from the local files, so nothing is downloaded: with every
file present, sncosmo's own SALT2Source/SALT3Source constructor; when the error-model
files are absent (the repository's salt2-jla-b14 keeps only M0, M1 and the colour
law) the same class with only M0, M1 (sncosmo's BicubicInterpolator) and the colour
law (sncosmo's SALT2ColorLaw) set, which is all that the flux uses.
If sncosmo cannot be imported the script prints "NO_SNCOSMO <reason>" and exits 3.
"""
import os
import sys
import warnings


def main():
    if len(sys.argv) != 3:
        sys.stderr.write(__doc__)
        return 2
    model_dir, jobs_file = sys.argv[1], sys.argv[2]
    warnings.simplefilter("ignore")
    try:
        import numpy as np
        from astropy.utils.data import conf as astropy_data_conf
        astropy_data_conf.allow_internet = False
        import sncosmo
        from sncosmo.models import read_griddata_ascii
        from sncosmo.salt2utils import BicubicInterpolator
    except Exception as e:  # noqa: BLE001 - any import failure means "no sncosmo"
        print("NO_SNCOSMO %s: %s" % (type(e).__name__, e))
        return 3

    if os.path.exists(os.path.join(model_dir, "salt3_template_0.dat")):
        prefix, cls = "salt3", sncosmo.SALT3Source
    else:
        prefix, cls = "salt2", sncosmo.SALT2Source
    files = {k: os.path.join(model_dir, "%s_%s.dat" % (prefix, k))
             for k in ("template_0", "template_1", "color_correction")}

    how = "full constructor"
    try:
        source = cls(modeldir=model_dir)
    except (OSError, IOError):
        how = "M0, M1 and colour law only (error-model files absent)"
        source = cls.__new__(cls)
        source.name = prefix
        source.version = "local"
        source._model = {}
        source._parameters = np.array([1.0, 0.0, 0.0])
        for key, f in (("M0", files["template_0"]), ("M1", files["template_1"])):
            phase, wave, values = read_griddata_ascii(f)
            values *= cls._SCALE_FACTOR
            source._model[key] = BicubicInterpolator(phase, wave, values)
            if key == "M0":
                source._phase = phase
                source._wave = wave
        source._set_colorlaw_from_file(files["color_correction"])

    print("# sncosmo %s, %s %s" % (sncosmo.__version__, cls.__name__, how))
    model = sncosmo.Model(source=source)
    bands = {}
    with open(jobs_file) as fp:
        for line in fp:
            if not line.strip() or line.startswith("#"):
                continue
            f = line.split()
            band_file = f[0]
            z, x0, x1, c, t0, mjd = (float(v) for v in f[1:7])
            if band_file not in bands:
                wave_nm, trans = np.loadtxt(band_file, unpack=True)
                bands[band_file] = sncosmo.Bandpass(wave_nm * 10.0, trans,
                                                    name=os.path.basename(band_file))
            model.set(z=z, t0=t0, x0=x0, x1=x1, c=c)
            try:
                flux = model.bandflux(bands[band_file], mjd)
            except ValueError:
                print("out")
                continue
            if not flux > 0:
                print("zero")
                continue
            print("%.8f" % model.bandmag(bands[band_file], "ab", mjd))
    return 0


if __name__ == "__main__":
    sys.exit(main())
