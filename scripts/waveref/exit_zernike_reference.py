#!/usr/bin/env python3
"""Zernike Standard coefficients fitted in normalised EXIT-pupil coordinates, from optiland 0.6.3's rays.

OpticStudio fits its Zernike terms over the exit pupil; optiland (and batoid) fit over the entrance
pupil, so no second engine prints exit-pupil coefficients. This script makes them from optiland's
own rays by the definition tolray documents for `--zernike-pupil exit` (docs/wave-optics.md,
"Conventions"), so that tolray's exit-pupil fit is checked against rays it did not trace:

  * the cases, lenses, quadrature and OPD are those of wave_reference.py (same 12 x 36 polar Gauss
    points over the normalised entrance pupil, same adaptations, optiland's paraxial ray aiming,
    apertures kept, vignetted points dropped);
  * each ray's point on the reference sphere is optiland's own (WavefrontData.pupil_x/y/z of its
    chief-ray strategy: the ray's image point moved back along the ray to the sphere centred on
    the chief ray's image point through the paraxial exit pupil);
  * the chief ray's point on the sphere likewise (the point Px = Py = 0 appended to the points);
  * normalised exit-pupil coordinates: (x - x_chief, y - y_chief) / (XPD / 2), optiland's global
    frame (every image plane here is normal to the axis), XPD optiland's paraxial exit-pupil
    diameter at the primary wavelength;
  * 37 Noll-ordered, orthonormal Zernike terms (wave_reference.zernike_noll) by weighted least
    squares with the quadrature weights renormalised over the points that get through.

Versions: as scripts/requirements.txt (optiland 0.6.3, numpy 2.4.6). Generated once, 2026-11-29;
the Rust test (tests/optics/wave_reference.rs, exit_pupil_zernikes_agree_with_optiland_rays)
reads the output and never runs this.

Usage (from the repository root):
    python3 -m venv .venv-ref && .venv-ref/bin/pip install -r scripts/requirements.txt
    .venv-ref/bin/python scripts/waveref/exit_zernike_reference.py
writes tests/data/wave/optiland_exit_zernike.json (about 20 seconds).
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import platform
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import wave_reference as wr  # noqa: E402
from optiland.wavefront import Wavefront  # noqa: E402

OUT = os.path.join(wr.ROOT, "tests", "data", "wave", "optiland_exit_zernike.json")
DATE = "2026-11-29"


def case(op, field_value, Hy, wl, qx, qy, qw):
    field = (0.0, float(Hy))
    px, py = np.append(qx, 0.0), np.append(qy, 0.0)
    wf = Wavefront(op, fields=[field], wavelengths=[wl], distribution=wr.PointsDistribution(px, py),
                   strategy="chief_ray", remove_tilt=False)
    d = wf.get_data(field, wl)
    inten = wr.arr(d.intensity)
    xs, ys = wr.arr(d.pupil_x), wr.arr(d.pupil_y)
    opd = wr.arr(d.opd)
    ok = (inten[:-1] > 0) & np.isfinite(xs[:-1]) & np.isfinite(ys[:-1])
    r_xp = 0.5 * wr.fl(op.paraxial.XPD())
    ex = (xs[:-1] - xs[-1]) / r_xp
    ey = (ys[:-1] - ys[-1]) / r_xp
    w = qw[ok] / qw[ok].sum()
    z_exit = wr.wls(wr.zernike_noll(ex[ok], ey[ok], 37), opd[:-1][ok], w)
    z_entrance = wr.wls(wr.zernike_noll(qx[ok], qy[ok], 37), opd[:-1][ok], w)
    return {
        "field": {"y": field_value}, "wavelength_nm": round(wl * 1000.0, 9),
        "rays_used": int(ok.sum()), "rays": int(len(qx)),
        "exit_pupil_radius_mm": r_xp,
        "chief_sphere_point_mm": [float(xs[-1]), float(ys[-1]), float(wr.arr(d.pupil_z)[-1])],
        "max_abs_exit_coordinate": float(np.max(np.hypot(ex[ok], ey[ok]))),
        "zernike_standard_exit_waves": [float(v) for v in z_exit],
        "zernike_standard_entrance_waves": [float(v) for v in z_entrance],
        "max_exit_minus_entrance_j4_waves": float(np.max(np.abs(z_exit[3:] - z_entrance[3:]))),
    }


def main():
    qx, qy, qw = wr.quadrature()
    lenses = []
    for lens in wr.LENSES:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            op, patches, adapt, feat = wr.load(lens)
            field_value, _ = wr.choose_field(op, lens, adapt)
        wl = wr.fl(op.primary_wavelength)
        fmax = wr.fl(wr.be.array(op.fields.max_field))
        cases = [(0.0, 0.0, wl), (field_value, field_value / fmax, wl)]
        out = {"id": lens["id"], "cases": []}
        for fv, Hy, w in cases:
            with contextlib.redirect_stdout(buf):
                c = case(op, fv, Hy, w, qx, qy, qw)
            print(lens["id"], fv, "exit - entrance (j >= 4):", c["max_exit_minus_entrance_j4_waves"],
                  flush=True)
            out["cases"].append(c)
        lenses.append(out)
    header = {
        "generator": "scripts/waveref/exit_zernike_reference.py",
        "date": DATE,
        "engine": "optiland " + __import__("importlib.metadata").metadata.version("optiland"),
        "versions": {"python": platform.python_version(), "numpy": np.__version__},
        "definition": "normalised exit-pupil coordinates = (sphere point - chief ray's sphere point)"
                      " x, y / (XPD/2), optiland global frame; 37 Noll orthonormal terms by WLS with"
                      " the entrance-pupil quadrature weights renormalised over the rays used",
        "cases": "as tests/data/wave/optiland_wave.json (same lenses, fields, quadrature)",
    }
    with open(OUT, "w") as fh:
        json.dump({"header": header, "lenses": lenses}, fh, indent=1)
        fh.write("\n")
    print("wrote", OUT)


if __name__ == "__main__":
    main()
